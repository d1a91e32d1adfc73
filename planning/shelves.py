"""Synthetic shelves: structured and unstructured stacks of the method's box types.

Boxes are placed geometrically (a height map over the shelf floor gives the
surface a box would land on, an exact oriented-box test refuses overlaps, a
support test refuses boxes whose centre of mass is not over what holds them),
then the scene is settled in the physics simulation (`ShelfSim`); a scene that
does not come to rest, or in which a box slid or fell far, is dropped and the
next attempt (derived from the same seed) is tried. Same seed, same scene.

Box types (cm, width x depth x height along the shelf's x, y, z): 23x31x25,
20x20x20, 50x17x17 lying, and 50x17x17 standing (17 wide, 50 tall; only in
unstructured stacks, where it leans against a stack or a side wall).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Literal, Sequence

import numpy as np

from perception.errors import SceneError, ShelfpickError
from perception.scene import Box, Scene, Shelf, quat_to_matrix

Kind = Literal["structured", "unstructured"]
KINDS: tuple[str, ...] = ("structured", "unstructured")

SHELF = Shelf(1.0, 0.30, 1.60)
# (name, size along x, y, z) in metres
BOX_TYPES: dict[str, tuple[float, float, float]] = {
    "carton": (0.23, 0.31, 0.25),
    "cube": (0.20, 0.20, 0.20),
    "long": (0.50, 0.17, 0.17),
}
STANDING_LONG = (0.17, 0.17, 0.50)

MAX_BOXES = 40
FRONT_MIN, FRONT_MAX = -0.05, 0.05   # y of the front face (boxes stick out up to 5 cm)
GAP = 0.004                          # clearance kept between placed boxes, m
CELL = 0.005                         # height-map resolution, m
Y_MIN_GRID = -0.12                   # the grid covers the part of boxes sticking out in front
MAX_ATTEMPTS = 60
SETTLE_MOVE_LIMIT = 0.03             # a box that moved more than this while settling: drop the scene
SETTLE_TURN_LIMIT = 12.0             # degrees


@dataclass
class _Placed:
    size: tuple[float, float, float]
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    leaning: bool = False

    def box(self, bid: str) -> Box:
        return Box(bid, self.size, self.position, self.orientation)


# --------------------------------------------------------------------------
# geometry helpers
def _quat_mul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    w1, x1, y1, z1 = a
    w2, x2, y2, z2 = b
    return (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)


def _axis_quat(axis: Sequence[float], angle: float) -> tuple[float, float, float, float]:
    s = math.sin(angle / 2)
    return (math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s)


def obb_overlap(a: _Placed, b: _Placed, margin: float = 0.0) -> bool:
    """Separating-axis test for two oriented boxes, each grown by `margin` on every side."""
    ra = np.array(quat_to_matrix(a.orientation))
    rb = np.array(quat_to_matrix(b.orientation))
    ha = np.array(a.size) / 2 + margin
    hb = np.array(b.size) / 2 + margin
    t = np.array(b.position) - np.array(a.position)
    axes = [ra[:, i] for i in range(3)] + [rb[:, i] for i in range(3)]
    for i in range(3):
        for j in range(3):
            c = np.cross(ra[:, i], rb[:, j])
            n = np.linalg.norm(c)
            if n > 1e-9:
                axes.append(c / n)
    for ax in axes:
        pa = sum(ha[k] * abs(ax @ ra[:, k]) for k in range(3))
        pb = sum(hb[k] * abs(ax @ rb[:, k]) for k in range(3))
        if abs(t @ ax) > pa + pb:
            return False
    return True


class _Layout:
    """The growing arrangement: placed boxes plus a height map of their tops."""

    def __init__(self, shelf: Shelf):
        self.shelf = shelf
        self.xs = np.arange(-shelf.width / 2 + CELL / 2, shelf.width / 2, CELL)
        self.ys = np.arange(Y_MIN_GRID + CELL / 2, shelf.depth, CELL)
        self.gx, self.gy = np.meshgrid(self.xs, self.ys, indexing="ij")
        self.height = np.zeros(self.gx.shape)
        # the floor supports only inside the shelf (y >= 0); in front of it there is nothing
        self.support = self.gy >= 0.0
        self.placed: list[_Placed] = []

    def footprint(self, cx: float, cy: float, sx: float, sy: float, yaw: float) -> np.ndarray:
        c, s = math.cos(yaw), math.sin(yaw)
        r = math.hypot(sx, sy) / 2
        i0, i1 = np.searchsorted(self.xs, [cx - r, cx + r])
        j0, j1 = np.searchsorted(self.ys, [cy - r, cy + r])
        out = np.zeros(self.gx.shape, dtype=bool)
        dx, dy = self.gx[i0:i1, j0:j1] - cx, self.gy[i0:i1, j0:j1] - cy
        u = c * dx + s * dy
        v = -s * dx + c * dy
        out[i0:i1, j0:j1] = (np.abs(u) <= sx / 2) & (np.abs(v) <= sy / 2)
        return out

    def fits_shelf(self, p: _Placed) -> bool:
        cs = np.array(p.box("_").corners())
        s = self.shelf
        return (cs[:, 0].min() >= -s.width / 2 + GAP and cs[:, 0].max() <= s.width / 2 - GAP
                and cs[:, 1].max() <= s.depth - GAP and cs[:, 1].min() >= Y_MIN_GRID
                and cs[:, 2].min() >= -1e-9 and cs[:, 2].max() <= s.height - GAP)

    def collides(self, p: _Placed) -> bool:
        # neighbours keep GAP between them; the quick distance check skips far boxes
        for q in self.placed:
            d = np.linalg.norm(np.array(p.position) - np.array(q.position))
            if d > (np.linalg.norm(p.size) + np.linalg.norm(q.size)) / 2 + 2 * GAP:
                continue
            if obb_overlap(p, q, GAP / 2 - 1e-6):
                return True
        return False

    def upright(self, size: tuple[float, float, float], cx: float, cy: float, yaw: float,
                min_support: float) -> _Placed | None:
        """An upright box (turned about z only) dropped at (cx, cy), or None if it cannot rest."""
        mask = self.footprint(cx, cy, size[0], size[1], yaw)
        if not mask.any():
            return None
        base = float(self.height[mask].max())
        sup = mask & self.support & (self.height >= base - 0.004)
        if sup.sum() < 4 or sup.sum() < min_support * mask.sum():
            return None
        if not _inside_hull(self.gx[sup], self.gy[sup], cx, cy, inset=0.02):
            return None
        p = _Placed(size, (cx, cy, base + size[2] / 2 + GAP), (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)))
        if not self.fits_shelf(p) or self.collides(p):
            return None
        return p

    def add(self, p: _Placed) -> None:
        self.placed.append(p)
        cs = np.array(p.box("_").corners())
        if p.leaning:
            # nothing may stand on a leaning box: raise its whole bounding rectangle, no support
            mask = ((self.gx >= cs[:, 0].min() - GAP) & (self.gx <= cs[:, 0].max() + GAP)
                    & (self.gy >= cs[:, 1].min() - GAP) & (self.gy <= cs[:, 1].max() + GAP))
            self.height[mask] = np.maximum(self.height[mask], cs[:, 2].max())
            self.support[mask] = False
            return
        yaw = 2 * math.atan2(p.orientation[3], p.orientation[0])
        mask = self.footprint(p.position[0], p.position[1], p.size[0], p.size[1], yaw)
        top = float(cs[:, 2].max())
        self.height[mask] = top
        self.support[mask] = True


def _inside_hull(px: np.ndarray, py: np.ndarray, cx: float, cy: float, inset: float) -> bool:
    """Is (cx, cy) at least `inset` inside the convex hull of the support points?"""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.column_stack([px, py])
    if len(pts) < 3:
        return False
    try:
        hull = ConvexHull(pts)
    except QhullError:
        return False
    # equations: normal . p + offset <= 0 inside; distance to each facet must exceed inset
    d = hull.equations[:, :2] @ np.array([cx, cy]) + hull.equations[:, 2]
    return bool(np.all(d <= -inset))


# --------------------------------------------------------------------------
def _front_y(rng: np.random.Generator, depth: float, shelf: Shelf) -> float:
    """A front-face y in [FRONT_MIN, FRONT_MAX] that keeps the back off the back wall."""
    hi = min(FRONT_MAX, shelf.depth - GAP - depth)
    return float(rng.uniform(FRONT_MIN, max(FRONT_MIN, hi)))


def _structured(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    """Rows and columns: a bottom row of stacks side by side, layers stacked on each column."""
    lay = _Layout(shelf)
    types = list(BOX_TYPES.values())
    # columns: left to right, each with a base type and a small gap
    columns: list[tuple[float, tuple[float, float, float]]] = []
    x = -shelf.width / 2 + GAP + float(rng.uniform(0.0, 0.04))
    while True:
        t = _pick_type(rng, types, n)
        if x + t[0] > shelf.width / 2 - GAP:
            # try a narrower type in the remaining space
            fitting = [u for u in types if x + u[0] <= shelf.width / 2 - GAP]
            if not fitting:
                break
            t = fitting[int(rng.integers(len(fitting)))]
        columns.append((x + t[0] / 2, t))
        x += t[0] + float(rng.uniform(0.005, 0.03))
    placed = 0
    stuck = 0
    tops = [0.0] * len(columns)
    while placed < n and stuck < 150:
        # rows: fill the lower columns first, so layers build up side by side
        low = min(tops)
        choice = [i for i, h in enumerate(tops) if h <= low + 0.15]
        ci = choice[int(rng.integers(len(choice)))]
        cx, base_t = columns[ci]
        # mostly the column's own type; sometimes another type that fits on it
        t = base_t if rng.random() < 0.7 else _pick_type(rng, types, n)
        jitter = float(rng.uniform(-0.01, 0.01))
        fy = _front_y(rng, t[1], shelf)
        p = lay.upright(t, cx + jitter, fy + t[1] / 2, 0.0, min_support=0.5)
        if p is None or p.position[2] + t[2] / 2 > _cap(n):
            stuck += 1
            if p is None and rng.random() < 0.02:
                tops[ci] = 9.0  # this column takes nothing more
            continue
        lay.add(p)
        tops[ci] = p.position[2] + t[2] / 2
        placed += 1
    return lay.placed


def _lean(lay: _Layout, rng: np.random.Generator, shelf: Shelf) -> _Placed | None:
    """A standing 50 cm box leaning sideways against a side wall or a stack taller than its contact."""
    w, d, h = STANDING_LONG
    phi = math.radians(float(rng.uniform(24.0, 32.0)))
    side = 1 if rng.random() < 0.5 else -1            # +1: leans to the right
    fy = _front_y(rng, d, shelf)
    cy = fy + d / 2
    contact_z = h * math.cos(phi)
    # what it can lean on: the side wall, or the side face of a placed upright box tall enough
    walls = [side * shelf.width / 2]
    for q in lay.placed:
        if q.leaning or abs(q.orientation[3]) > 1e-6:
            continue
        top = q.position[2] + q.size[2] / 2
        y0, y1 = q.position[1] - q.size[1] / 2, q.position[1] + q.size[1] / 2
        if top < contact_z + 0.03 or y1 < cy + 0.02 or y0 > cy - 0.02:
            continue
        walls.append(q.position[0] - side * q.size[0] / 2)
    rng.shuffle(walls)
    for xw in walls:
        xw = float(xw) - side * 0.002
        # pivot (lowest edge on the floor) sits h sin(phi) away from the wall
        pivot_x = xw - side * h * math.sin(phi)
        rot = _axis_quat((0.0, 1.0, 0.0), side * phi)
        r = np.array(quat_to_matrix(rot))
        # lowest corner in local coordinates: (side * w/2, -h/2)
        local = np.array([side * w / 2, 0.0, -h / 2])
        centre = np.array([pivot_x, cy, GAP]) - r @ local
        p = _Placed((w, d, h), tuple(float(v) for v in centre), rot, leaning=True)
        # the floor under the pivot must be empty and inside the shelf
        if not lay.fits_shelf(p) or lay.collides(p):
            continue
        mask = lay.footprint(pivot_x, cy, 0.02, d, 0.0)
        if mask.any() and lay.height[mask].max() > 1e-6:
            continue
        if cy - d / 2 < -0.02:  # the pivot edge must stand on the floor, not in front of it
            continue
        return p
    return None


def _unstructured(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    """Random positions, in-plane turns, overhangs, bridges and the odd leaning box."""
    lay = _Layout(shelf)
    types = list(BOX_TYPES.values())
    lean_at = int(rng.integers(max(1, n // 2), max(2, n))) if rng.random() < 0.6 else -1
    stuck = 0
    while len(lay.placed) < n and stuck < (40 if n <= 16 else 100):
        if len(lay.placed) == lean_at:
            p = _lean(lay, rng, shelf)
            lean_at = -1
            if p is not None:
                lay.add(p)
            continue
        t = _pick_type(rng, types, n)
        yaw = float(rng.uniform(-0.35, 0.35)) if rng.random() < 0.6 else 0.0
        uprights = [q for q in lay.placed if not q.leaning]
        # a bridge: the long box across two neighbouring tops of about the same height
        pairs = [(a, b) for i, a in enumerate(uprights) for b in uprights[i + 1:]
                 if abs(a.position[2] + a.size[2] / 2 - b.position[2] - b.size[2] / 2) < 0.01
                 and 0.15 < abs(a.position[0] - b.position[0]) < 0.4]
        if pairs and rng.random() < 0.25:
            a, b = pairs[int(rng.integers(len(pairs)))]
            t = BOX_TYPES["long"]
            cx = (a.position[0] + b.position[0]) / 2 + float(rng.uniform(-0.03, 0.03))
            yaw = float(rng.uniform(-0.1, 0.1))
        else:
            # several random drops (near a box: stacks and overhangs; anywhere: new piles);
            # the lowest wins, so piles grow from the floor as a real shelf fills
            valid = []
            for _ in range(10 if n <= 16 else 20):
                u = rng.random()
                if u < 0.3 and uprights:
                    q = uprights[int(rng.integers(len(uprights)))]
                    cx = q.position[0] + float(rng.uniform(-0.15, 0.15))
                elif u < 0.6 and uprights:
                    # beside a box (packs the floor and the layers densely)
                    q = uprights[int(rng.integers(len(uprights)))]
                    qyaw = abs(2 * math.atan2(q.orientation[3], q.orientation[0]))
                    qw = q.size[0] * math.cos(qyaw) + q.size[1] * math.sin(qyaw)
                    tw = t[0] * math.cos(abs(yaw)) + t[1] * math.sin(abs(yaw))
                    side = 1 if rng.random() < 0.5 else -1
                    cx = q.position[0] + side * ((qw + tw) / 2 + float(rng.uniform(0.006, 0.03)))
                elif u < 0.8:
                    cx = _low_spot(lay, rng, t[0] + 0.02)
                else:
                    cx = float(rng.uniform(-shelf.width / 2 + t[0] / 2, shelf.width / 2 - t[0] / 2))
                p = _drop(lay, rng, t, cx, yaw, shelf)
                if p is not None:
                    valid.append(p)
            valid.sort(key=lambda v: v.position[2] - v.size[2] / 2)
            best = None
            if valid:
                best = valid[0] if rng.random() < 0.75 else valid[int(rng.integers(len(valid)))]
            if best is None or best.position[2] + t[2] / 2 > _cap(n):
                stuck += 1
                continue
            lay.add(best)
            continue
        p = _drop(lay, rng, t, cx, yaw, shelf)
        if p is None or p.position[2] + t[2] / 2 > _cap(n):
            stuck += 1
            continue
        lay.add(p)
    return lay.placed


def _drop(lay: _Layout, rng: np.random.Generator, t: tuple[float, float, float], cx: float,
          yaw: float, shelf: Shelf) -> _Placed | None:
    """An upright box turned by (at most) `yaw` dropped at x = cx with a random front offset."""
    # a turned box reaches deeper: keep its footprint inside the 30 cm (plus 5 cm in front)
    limit = math.asin(0.03 / t[0]) if t[1] > 0.28 else (0.12 if t[0] > 0.4 else 0.35)
    yaw = max(-limit, min(limit, yaw))
    extent = t[1] * math.cos(yaw) + t[0] * abs(math.sin(yaw))
    fy = _front_y(rng, extent, shelf)
    return lay.upright(t, cx, fy + extent / 2, yaw, min_support=0.3)


def _low_spot(lay: _Layout, rng: np.random.Generator, width: float) -> float:
    """An x where a box of this width would land low: a gap in the piles, picked at random."""
    profile = lay.height.max(axis=1)              # highest top across the depth, per x cell
    k = max(1, int(round(width / CELL)))
    windows = np.lib.stride_tricks.sliding_window_view(profile, k).max(axis=1)
    low = np.flatnonzero(windows <= windows.min() + 0.01)
    i = int(low[int(rng.integers(len(low)))])
    return float(lay.xs[i] + (k - 1) * CELL / 2)


def _pick_type(rng: np.random.Generator, types: list, n: int) -> tuple[float, float, float]:
    """Uniform over the types; large scenes favour the 20 cm cube so that 30 boxes fit."""
    if n > 16:
        w = np.array([0.15, 0.7, 0.15])
        return types[int(rng.choice(len(types), p=w))]
    return types[int(rng.integers(len(types)))]


def _cap(n: int) -> float:
    """Highest top a box may reach: small scenes stay low, large ones use the shelf's height."""
    return 1.3 if n <= 16 else SHELF.height - 0.05


# --------------------------------------------------------------------------
def _order(boxes: list[Box]) -> list[Box]:
    """Bottom-up (by the lowest corner, 2 cm bands), then left to right."""
    def key(b: Box) -> tuple[int, float]:
        zmin = min(c[2] for c in b.corners())
        return (int(round(zmin / 0.02)), b.position[0])
    return sorted(boxes, key=key)


def layout(kind: str, seed: int, n_boxes: int | None = None, attempt: int = 0) -> Scene:
    """The geometric placement alone (not settled): what `generate` hands to the simulation."""
    if kind not in KINDS:
        raise ShelfpickError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, KINDS.index(kind), attempt])
    n = int(rng.integers(8, 15)) if n_boxes is None else int(n_boxes)
    if not 1 <= n <= MAX_BOXES:
        raise ShelfpickError(f"n_boxes: expected 1..{MAX_BOXES}, got {n_boxes!r}")
    placed = (_structured if kind == "structured" else _unstructured)(rng, n, SHELF)
    boxes = _order([p.box("_") for p in placed])
    boxes = [Box(f"b{i}", b.size, b.position, b.orientation) for i, b in enumerate(boxes)]
    return Scene(SHELF, tuple(boxes), source={"generator": "shelfpick.shelves", "kind": kind,
                                               "seed": int(seed), "attempt": attempt, "n_boxes": n})


def _settle(scene: Scene) -> Scene:
    """Settle in the physics simulation; SceneError if it does not rest or boxes moved far."""
    from planning.sim import ShelfSim

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ShelfSim(scene)
    try:
        settled = sim.scene
        present = set(sim.present())
    finally:
        sim.close()
    if present != set(scene.ids):
        raise SceneError(f"boxes fell off while settling: {sorted(set(scene.ids) - present)}")
    after = {b.id: b for b in settled.boxes}
    for b in scene.boxes:
        a = after[b.id]
        move = math.dist(a.position, b.position)
        dot = abs(sum(x * y for x, y in zip(a.orientation, b.orientation)))
        turn = math.degrees(2 * math.acos(min(1.0, dot)))
        if move > SETTLE_MOVE_LIMIT or turn > SETTLE_TURN_LIMIT:
            raise SceneError(f"box {b.id} moved {move * 100:.1f} cm / {turn:.0f} deg while settling")
        if min(c[2] for c in a.corners()) < -0.01:
            raise SceneError(f"box {b.id} fell below the shelf floor")
    return settled


def generate(kind: str, seed: int, n_boxes: int | None = None, *, settle: bool = True) -> Scene:
    """A settled synthetic shelf, ids b0..bN-1 bottom-up then left to right. Same seed, same scene.

    Attempts whose layout cannot take all the boxes, or which do not settle
    calmly, are dropped; the next attempt is derived from the same seed.
    """
    last = ""
    for attempt in range(MAX_ATTEMPTS):
        scene = layout(kind, seed, n_boxes, attempt)
        want = scene.source["n_boxes"]
        if len(scene.boxes) != want:
            last = f"only {len(scene.boxes)} of {want} boxes fit"
            continue
        if not settle:
            return scene
        try:
            settled = _settle(scene)
        except SceneError as exc:
            last = str(exc)
            continue
        boxes = _order(list(settled.boxes))
        rename = [Box(f"b{i}", b.size, b.position, b.orientation) for i, b in enumerate(boxes)]
        return Scene(SHELF, tuple(rename), source=scene.source)
    raise SceneError(f"no {kind} shelf with {n_boxes} boxes for seed {seed} after "
                     f"{MAX_ATTEMPTS} attempts (last: {last})")
