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

Besides `structured` and `unstructured`, four kinds where the highest-first
baseline collapses often (HARD_KINDS, docs/bench.md): `proud` (columns where
half the boxes stick 1-6 cm out of the shelf front, carrying set-back boxes),
`bridge` (piles with up to three long boxes across two supports), `lean` (columns
and a long box leaning on a box that reaches above it), `overhang` (turned,
shifted columns at any size). These carry true masses (0.3-5 kg per box) and are
settled with them: every shelf written is at rest, a truth.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from typing import Literal, Sequence

import numpy as np

from perception.errors import SceneError, ShelfpickError
from perception.scene import BOX_TYPES, Box, Scene, Shelf, quat_to_matrix
from planning.geometry3 import rot_angle_deg
from planning.sim import ShelfSim

Kind = Literal["structured", "unstructured", "proud", "bridge", "lean", "overhang"]
# the last four are stacks where the highest-first baseline collapses often (docs/bench.md):
# boxes proud of the front carrying others, long boxes bridging two supports, boxes leaning on a
# stack, boxes turned and shifted over the one below
KINDS: tuple[str, ...] = ("structured", "unstructured", "proud", "bridge", "lean", "overhang")
HARD_KINDS: tuple[str, ...] = KINDS[2:]
MASS_RANGE = (0.3, 5.0)              # kg, true masses drawn per box (the hard kinds; --masses)
PROUD_RANGE = (0.01, 0.06)           # m a proud box's front face sticks out of the shelf front

SHELF = Shelf()                     # 100 x 30 x 160 cm, the method's (perception.scene)
STANDING_LONG = (0.17, 0.17, 0.50)

MAX_BOXES = 30
DENSE_FROM = 16                      # unstructured scenes above this size: turned, shifted columns
FRONT_MIN, FRONT_MAX = -0.05, 0.05   # y of the front face (boxes stick out up to 5 cm)
GAP = 0.004                          # clearance kept between placed boxes, m
CELL = 0.005                         # height-map resolution, m
Y_MIN_GRID = -0.12                   # the grid covers the part of boxes sticking out in front
MAX_ATTEMPTS = 60
STILL_TIME = 1.0                     # a settled shelf left alone this long ...
STILL_LIMIT = 0.01                   # ... moves no box more than this, or it is dropped
SETTLE_MOVE_LIMIT = 0.03             # a box that moved more than this while settling: drop the scene
SETTLE_TURN_LIMIT = 12.0             # degrees


@dataclass
class _Placed:
    size: tuple[float, float, float]
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    leaning: bool = False
    sole: int | None = None          # index of the one box it rests on (None: floor, or shared support)
    hull: np.ndarray | None = None   # its support polygon (convex hull equations, xy)

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
        self.owner = np.full(self.gx.shape, -1, dtype=int)   # which box's top is the surface here
        self.placed: list[_Placed] = []
        self.load: list[list[int]] = []                    # boxes resting (through sole supports) on each

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
        hull = _hull(self.gx[sup], self.gy[sup])
        if hull is None or not _inside(hull, cx, cy, inset=0.02):
            return None
        owners = np.unique(self.owner[sup])
        sole = int(owners[0]) if len(owners) == 1 and owners[0] >= 0 else None
        p = _Placed(size, (cx, cy, base + size[2] / 2 + GAP), (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
                    sole=sole, hull=hull)
        if not self.fits_shelf(p) or self.collides(p) or not self.carries(p):
            return None
        return p

    def carries(self, p: _Placed) -> bool:
        """Does every box below p (down a chain of sole supports) keep the load's centre of mass
        inside its own support polygon? (A box resting on two supports shares the load: not followed.)"""
        vol = p.size[0] * p.size[1] * p.size[2]
        s = p.sole
        while s is not None:
            q = self.placed[s]
            members = [q] + [self.placed[i] for i in self.load[s]]
            vols = [m.size[0] * m.size[1] * m.size[2] for m in members] + [vol]
            xs = [m.position[0] for m in members] + [p.position[0]]
            ys = [m.position[1] for m in members] + [p.position[1]]
            tot = sum(vols)
            cx = sum(v * x for v, x in zip(vols, xs)) / tot
            cy = sum(v * y for v, y in zip(vols, ys)) / tot
            if q.hull is None or not _inside(q.hull, cx, cy, inset=0.015):
                return False
            s = q.sole
        return True

    def add(self, p: _Placed) -> None:
        idx = len(self.placed)
        self.placed.append(p)
        self.load.append([])
        s = p.sole
        while s is not None:
            self.load[s].append(idx)
            s = self.placed[s].sole
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
        self.owner[mask] = idx


def _hull(px: np.ndarray, py: np.ndarray) -> np.ndarray | None:
    """Convex hull equations (normal . p + offset <= 0 inside) of support points; None if degenerate."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.column_stack([px, py])
    if len(pts) < 3:
        return None
    try:
        return ConvexHull(pts).equations
    except QhullError:
        return None


def _inside(hull: np.ndarray, cx: float, cy: float, inset: float) -> bool:
    """Is (cx, cy) at least `inset` inside the hull?"""
    d = hull[:, :2] @ np.array([cx, cy]) + hull[:, 2]
    return bool(np.all(d <= -inset))


# --------------------------------------------------------------------------
def _front_y(rng: np.random.Generator, depth: float, shelf: Shelf) -> float:
    """A front-face y in [FRONT_MIN, FRONT_MAX] that keeps the back off the back wall."""
    hi = min(FRONT_MAX, shelf.depth - GAP - depth)
    return float(rng.uniform(FRONT_MIN, max(FRONT_MIN, hi)))


def _yaw_of(p: _Placed) -> float:
    return 2 * math.atan2(p.orientation[3], p.orientation[0])


def _extent(t: Sequence[float], yaw: float) -> tuple[float, float]:
    """Axis-aligned x and y extent of an upright box turned by yaw."""
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    return t[0] * c + t[1] * s, t[1] * c + t[0] * s


def _room(t: Sequence[float], top: float, cap: float) -> int:
    """How many boxes of type t still stack on a column whose top is at `top` under `cap`."""
    return max(0, int((cap - top + 1e-9) // (t[2] + GAP)))


def _draw_columns(rng: np.random.Generator, n: int, shelf: Shelf, cap: float,
                  slack: float) -> list[tuple[float, float, float]]:
    """Column types left to right: each needs its width + `slack`, together they hold >= n boxes.

    Random draws (cube-heavy for large n) first; if none holds n, the densest
    packing: 20 cm cube columns, then a standing 50 cm box column in what is left.
    """
    width = shelf.width - GAP
    small = n <= 16
    pool = [BOX_TYPES["carton"], BOX_TYPES["cube"], BOX_TYPES["long"]]
    fillers = pool + ([] if small else [STANDING_LONG])
    weights = np.array([1 / 3, 1 / 3, 1 / 3]) if small else np.array([0.1, 0.8, 0.1])
    for _ in range(12):
        cols: list[tuple[float, float, float]] = []
        used = 0.0
        while True:
            t = pool[int(rng.choice(3, p=weights))]
            if used + t[0] + slack + GAP > width:
                fitting = [u for u in fillers if used + u[0] + slack + GAP <= width]
                if not fitting:
                    break
                t = fitting[int(rng.integers(len(fitting)))]
            cols.append(t)
            used += t[0] + slack + GAP
        if sum(_room(t, 0.0, cap) for t in cols) >= n:
            return cols
    for s in (slack, 0.0):
        k = int(width // (0.20 + s + GAP))
        cols = [BOX_TYPES["cube"]] * k
        if width - k * (0.20 + s + GAP) >= STANDING_LONG[0] + s + GAP:
            cols.append(STANDING_LONG)
        if sum(_room(t, 0.0, cap) for t in cols) >= n:
            break
    order = rng.permutation(len(cols))
    return [cols[i] for i in order]


def _intervals(rng: np.random.Generator, cols: list[tuple[float, float, float]], shelf: Shelf,
               spread: str) -> list[tuple[float, float]]:
    """x intervals for the columns: the free width goes to the gaps ('gaps') or to the columns ('columns')."""
    free = shelf.width - sum(t[0] for t in cols) - (len(cols) + 1) * GAP
    k = len(cols)
    if spread == "gaps":
        share = rng.dirichlet(np.ones(k + 1)) * free
        x = -shelf.width / 2 + GAP + share[0]
        out = []
        for t, g in zip(cols, share[1:]):
            out.append((x, x + t[0]))
            x += t[0] + GAP + g
        return out
    share = rng.dirichlet(np.full(k, 2.0)) * free
    x = -shelf.width / 2 + GAP
    out = []
    for t, g in zip(cols, share):
        out.append((x, x + t[0] + g))
        x += t[0] + g + GAP
    return out


def _columns(rng: np.random.Generator, n: int, shelf: Shelf, unstructured: bool,
             proud: float = 0.0, cap: float | None = None) -> list[_Placed]:
    """Rows and columns: columns of one box type stacked bottom-up, the lowest filled first.

    Structured: upright boxes, a little x jitter, front faces sticking out by
    different amounts, now and then a narrower type on a column. Unstructured
    (the dense, 17+ box case): each column gets part of the free width, so its
    boxes turn in-plane and shift sideways over the box below (overhangs).
    Never short of room: the columns are drawn to hold n boxes.
    """
    cap = _cap(n) if cap is None else cap
    slack = 0.03 if unstructured else 0.0
    cols = _draw_columns(rng, n, shelf, cap, slack)
    spans = _intervals(rng, cols, shelf, "columns" if unstructured else "gaps")
    lay = _Layout(shelf)
    tops = [0.0] * len(cols)
    below: list[_Placed | None] = [None] * len(cols)
    def narrower(t: tuple[float, float, float]) -> list[tuple[float, float, float]]:
        return [u for u in (BOX_TYPES["cube"], BOX_TYPES["carton"]) if u[0] < t[0]]

    placed = 0
    while placed < n:
        rooms = [_room(t, h, cap) for t, h in zip(cols, tops)]
        left = n - placed
        open_cols = [i for i, r in enumerate(rooms) if r > 0]
        if not open_cols:
            break
        low = min(tops[i] for i in open_cols)
        band = 0.15 if n <= 16 else 0.05
        choice = [i for i in open_cols if tops[i] <= low + band]
        ci = choice[int(rng.integers(len(choice)))]
        t = cols[ci]
        # now and then a narrower type on this column, if the rest still fits
        if narrower(t) and rng.random() < (0.25 if n <= 16 else 0.1) and below[ci] is not None:
            u = narrower(t)[int(rng.integers(len(narrower(t))))]
            spare = sum(rooms) - rooms[ci] + _room(t, tops[ci] + u[2] + GAP, cap)
            if spare >= left - 1 and _room(u, tops[ci], cap) > 0:
                t = u
                cols[ci] = u   # the column goes on with the narrower type (a wide box would not rest on it)
        p = _place_in_column(lay, rng, t, spans[ci], below[ci], unstructured, proud)
        if p is None:
            tops[ci] = 9.0  # nothing more fits on this column
            continue
        lay.add(p)
        below[ci] = p
        tops[ci] = p.position[2] + t[2] / 2
        placed += 1
    return lay.placed


def _place_in_column(lay: _Layout, rng: np.random.Generator, t: tuple[float, float, float],
                     span: tuple[float, float], under: _Placed | None, turn: bool,
                     proud: float = 0.0) -> _Placed | None:
    """One box on a column: random front offset (kept over the box below), jitter or turn and shift.
    With `proud` > 0 that share of boxes sticks 1-6 cm out of the shelf front, and a box on a
    proud one sits further back (its centre still over the box below)."""
    shelf = lay.shelf
    if proud > 0.0:
        p = _place_proud(lay, rng, t, span, under, proud)
        if p is not None:
            return p
    for attempt in range(10):
        last = attempt == 9
        yaw = 0.0
        if turn and not last and rng.random() < 0.7:
            room = span[1] - span[0]
            # largest turn whose x extent still fits the column's span (and stays <= 0.3 rad)
            hi = 0.0
            for a in np.linspace(0.3, 0.0, 16):
                if _extent(t, a)[0] <= room - 1e-4 and t[1] * math.cos(a) + t[0] * math.sin(a) <= 0.33:
                    hi = float(a)
                    break
            yaw = float(rng.uniform(-hi, hi))
        ex, ey = _extent(t, yaw)
        free = max(0.0, (span[1] - span[0]) - ex)
        if last:
            cx = (span[0] + span[1]) / 2
        elif turn:
            cx = span[0] + ex / 2 + float(rng.uniform(0.0, free))
        else:
            j = min(0.005, free / 2)
            cx = (span[0] + span[1]) / 2 + float(rng.uniform(-j, j))
        hi_front = min(FRONT_MAX, shelf.depth - GAP - ey)
        if under is None:
            front = float(rng.uniform(FRONT_MIN, max(FRONT_MIN, hi_front)))
        else:
            # keep the centre well over the box below
            ucy = under.position[1]
            lo_c, hi_c = ucy - (0.0 if last else 0.04), ucy + (0.0 if last else 0.04)
            front = float(rng.uniform(lo_c, hi_c)) - ey / 2
            front = min(max(front, FRONT_MIN), max(FRONT_MIN, hi_front))
        p = lay.upright(t, cx, front + ey / 2, yaw, min_support=0.5)
        if p is not None:
            return p
    return None


def _place_proud(lay: _Layout, rng: np.random.Generator, t: tuple[float, float, float],
                 span: tuple[float, float], under: _Placed | None, share: float) -> _Placed | None:
    """An upright box whose front sticks out of the shelf (with chance `share`), or, on a box that
    does, one set back over it: heavy loads on a ledge the camera sees only from the front."""
    shelf = lay.shelf
    cx = (span[0] + span[1]) / 2
    for _ in range(6):
        if under is not None and under.position[1] - under.size[1] / 2 < 0.0:
            # on a proud box: set back, its centre 1-4 cm behind the centre of the box below
            cy = under.position[1] + float(rng.uniform(0.01, 0.04))
            cy = min(cy, shelf.depth - GAP - t[1] / 2)
        elif rng.random() < share:
            cy = -float(rng.uniform(*PROUD_RANGE)) + t[1] / 2
        else:
            return None
        p = lay.upright(t, cx + float(rng.uniform(-0.004, 0.004)), cy, 0.0, min_support=0.5)
        if p is not None:
            return p
    return None


def _lean(lay: _Layout, rng: np.random.Generator, shelf: Shelf) -> _Placed | None:
    """A standing 50 cm box leaning sideways against a side wall or a stack taller than its contact."""
    w, d, h = STANDING_LONG
    phi = math.radians(float(rng.uniform(24.0, 32.0)))
    side = 1 if rng.random() < 0.5 else -1            # +1: leans to the right
    fy = float(rng.uniform(-0.02, min(FRONT_MAX, shelf.depth - GAP - d)))  # the pivot edge stands on the floor
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
        p = _leaning_at(lay, float(xw), side, phi, cy)
        if p is not None:
            return p
    return None


def _leaning_at(lay: _Layout, xw: float, side: int, phi: float, cy: float) -> _Placed | None:
    """The standing long box leaning by `phi` towards `side` with its top edge on the wall at x = xw."""
    w, d, h = STANDING_LONG
    xw = xw - side * (GAP + 0.001)   # keep the clearance the overlap test asks for
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
        return None
    mask = lay.footprint(pivot_x, cy, 0.02, d, 0.0)
    if mask.any() and lay.height[mask].max() > 1e-6:
        return None
    if cy - d / 2 < -0.02:  # the pivot edge must stand on the floor, not in front of it
        return None
    return p


def _lean_on_stack(lay: _Layout, rng: np.random.Generator, side: int) -> _Placed | None:
    """A long box leaning (18-40 deg) on the side of a box that reaches 5 cm below the contact and
    above the leaning box's top: highest-first takes that box first and the leaning box falls far."""
    w, d, h = STANDING_LONG
    options = []
    for q in lay.placed:
        if q.leaning or abs(q.orientation[3]) > 1e-6:
            continue
        bottom, top = q.position[2] - q.size[2] / 2, q.position[2] + q.size[2] / 2
        for deg in range(18, 41):
            phi = math.radians(deg)
            contact = GAP + h * math.cos(phi)
            if contact - 0.05 >= bottom and contact + w * math.sin(phi) + 0.02 <= top:
                options.append((q, phi))
    for i in rng.permutation(len(options))[:12]:
        q, phi = options[int(i)]
        y0, y1 = q.position[1] - q.size[1] / 2, q.position[1] + q.size[1] / 2
        cy = float(rng.uniform(y0 + d / 2, max(y0 + d / 2, y1 - d / 2)))
        p = _leaning_at(lay, q.position[0] - side * q.size[0] / 2, side, phi, cy)
        if p is not None:
            return p
    return None


def _landing_spots(lay: _Layout, rng: np.random.Generator, t: tuple[float, float, float], yaw: float,
                   k: int, pile: bool) -> list[tuple[float, float]]:
    """Up to k centres (x, y) where the box would land low: a max filter over the height map gives
    the resting height of its (axis-aligned bounding) footprint at every cell at once."""
    from scipy.ndimage import maximum_filter

    shelf = lay.shelf
    ex, ey = _extent(t, yaw)
    kx, ky = max(1, int(math.ceil(ex / CELL))), max(1, int(math.ceil(ey / CELL)))
    # a raised cell that cannot hold anything (a leaning box's zone) blocks like a wall
    surface = np.where(lay.support | (lay.height <= 0.0), lay.height, 10.0)
    base = maximum_filter(surface, size=(kx, ky), mode="constant", cval=10.0)
    xs_ok = np.abs(lay.xs) <= shelf.width / 2 - GAP - ex / 2 - 1e-4
    hi_front = min(FRONT_MAX, shelf.depth - GAP - ey)
    fronts = np.linspace(FRONT_MIN, max(FRONT_MIN, hi_front), 5)
    rows = np.unique(np.clip(np.searchsorted(lay.ys, fronts + ey / 2), 0, len(lay.ys) - 1))
    sub = base[:, rows]
    sub = np.where(xs_ok[:, None], sub, np.inf)
    m = float(sub.min())
    if not math.isfinite(m):
        return []
    tol = float(rng.uniform(0.05, 0.25)) if pile else 0.02
    ii, jj = np.nonzero(sub <= m + tol)
    out: list[tuple[float, float]] = []
    # ends of low runs along x (packed against a neighbour or a wall) and random cells
    low_x = np.zeros(len(lay.xs), dtype=bool)
    low_x[ii] = True
    edges = np.flatnonzero(low_x & ~np.r_[False, low_x[:-1]]).tolist() + \
        np.flatnonzero(low_x & ~np.r_[low_x[1:], False]).tolist()
    picks = []
    for e in (rng.permutation(len(edges))[:max(1, k // 2)] if edges else []):
        at = np.flatnonzero(ii == int(edges[int(e)]))
        picks.append(int(at[int(rng.integers(len(at)))]))
    rest = list(rng.permutation(len(ii))[:k])
    # mostly packed against a neighbour (dense piles), sometimes anywhere low
    picks = picks + rest if rng.random() < 0.7 else rest + picks
    for p in picks[:k]:
        out.append((float(lay.xs[ii[p]]), float(lay.ys[rows[jj[p]]])))
    return out


def _scattered(rng: np.random.Generator, n: int, shelf: Shelf, bridges: int = 0) -> list[_Placed]:
    """Random piles for small scenes: random types and turns, each box dropped where it lands low
    (now and then on top of a pile: overhangs), long boxes bridging two tops, a leaning box.
    `bridges` > 0 asks for that many bridges instead of the usual chance of one."""
    lay = _Layout(shelf)
    types = list(BOX_TYPES.values())
    cap = SHELF.height - 0.05
    want_lean = rng.random() < 0.7
    # it needs free floor: mostly first (against a side wall), else later against a stack if there is room
    lean_from = 0 if rng.random() < 0.6 else int(rng.integers(1, max(2, n // 2)))
    want_bridge = rng.random() < 0.6
    n_lean, n_bridge = int(want_lean), int(want_bridge)
    if bridges:
        n_bridge = bridges
    stuck = 0
    while len(lay.placed) < n and stuck < 40:
        k = len(lay.placed)
        if n_lean and k >= lean_from:
            p = _lean(lay, rng, shelf)
            if p is not None:
                lay.add(p)
                n_lean -= 1
                continue
            if k > lean_from + 3:
                n_lean = 0
        if n_bridge and k >= 2:
            p = _bridge(lay, rng)
            if p is not None and p.position[2] + p.size[2] / 2 <= cap:
                lay.add(p)
                n_bridge -= 1
                continue
        t = types[int(rng.integers(len(types)))]
        yaw = float(rng.uniform(-0.35, 0.35)) if rng.random() < 0.6 else 0.0
        limit = math.asin(0.03 / t[0]) if t[1] > 0.28 else (0.12 if t[0] > 0.4 else 0.35)
        yaw = max(-limit, min(limit, yaw))
        best = None
        tries = [(t, yaw), (t, 0.0), (BOX_TYPES["cube"], 0.0)]
        if stuck >= 3:   # running out of room: any type, upright, more spots, on piles too
            tries += [(u, 0.0) for u in types]
        for tt, yy in tries:
            pile = rng.random() < (0.15 if stuck < 3 else 0.5)
            for cx, cy in _landing_spots(lay, rng, tt, yy, 6 if stuck < 3 else 12, pile=pile):
                p = lay.upright(tt, cx, cy, yy, min_support=0.3)
                if p is not None and p.position[2] + tt[2] / 2 <= cap:
                    best = p
                    break
            if best is not None:
                break
        if best is None:
            stuck += 1
            continue
        lay.add(best)
    return lay.placed


def _bridge(lay: _Layout, rng: np.random.Generator) -> _Placed | None:
    """A long box lying across two tops of about the same height with a gap between them."""
    t = BOX_TYPES["long"]
    ups = [q for q in lay.placed if not q.leaning]
    pairs = [(a, b) for i, a in enumerate(ups) for b in ups[i + 1:]
             if abs(a.position[2] + a.size[2] / 2 - b.position[2] - b.size[2] / 2) < 0.01
             and 0.15 < abs(a.position[0] - b.position[0]) < 0.42]
    for i in rng.permutation(len(pairs))[:6]:
        a, b = pairs[int(i)]
        cx = (a.position[0] + b.position[0]) / 2 + float(rng.uniform(-0.02, 0.02))
        yaw = float(rng.uniform(-0.08, 0.08))
        cy = (a.position[1] + b.position[1]) / 2 + float(rng.uniform(-0.02, 0.02))
        ex, ey = _extent(t, yaw)
        cy = min(max(cy, FRONT_MIN + ey / 2), lay.shelf.depth - GAP - ey / 2)
        p = lay.upright(t, cx, cy, yaw, min_support=0.2)
        if p is not None:
            return p
    return None


def _unstructured(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    """Small scenes: random piles; dense ones (more than 16 boxes): turned, shifted columns."""
    if n <= DENSE_FROM:
        return _scattered(rng, n, shelf)
    return _columns(rng, n, shelf, unstructured=True)


def _structured(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    return _columns(rng, n, shelf, unstructured=False)


LEAN_ROOM = 0.42   # m of floor kept free beside the columns for a leaning box


def _leaning_on_columns(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    """Columns on the left of the shelf, and a standing long box leaning on the rightmost one
    against a box that reaches above it (highest-first takes that box first); where the columns
    offer none, against the wall or any stack tall enough."""

    part = Shelf(shelf.width - LEAN_ROOM, shelf.depth, shelf.height)
    dx = -LEAN_ROOM / 2
    lay = _Layout(shelf)
    # up to the shelf's top: 13 boxes must fit in the narrower width
    for p in _columns(rng, n - 1, part, unstructured=False, cap=shelf.height - 0.05):
        hull = None if p.hull is None else p.hull - np.outer(p.hull[:, 0], [0.0, 0.0, dx])
        lay.add(replace(p, position=(p.position[0] + dx, p.position[1], p.position[2]), hull=hull))
    # columns that offer no such box: it leans on the wall or the stack as in unstructured piles
    lean = _lean_on_stack(lay, rng, side=-1) or _lean(lay, rng, shelf)
    if lean is not None:
        lay.add(lean)
    return lay.placed


def _leaning_on_overhang(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    """A long box lying on a column of two cubes (and on a second column if there is room),
    sticking 20-23 cm out on the right, a standing long box leaning (18-23 deg) on that end,
    and the rest dropped on top. Highest-first takes the long box before the leaning one
    (its top is higher), and the leaning box falls 20 cm onto the cubes."""
    cube, long_ = BOX_TYPES["cube"], BOX_TYPES["long"]
    w, d, h = STANDING_LONG
    lay = _Layout(shelf)
    phi = math.radians(float(rng.uniform(18.0, 23.0)))
    reach = h * math.sin(phi) + w * math.cos(phi) + 0.01        # floor the leaning box needs
    end = shelf.width / 2 - GAP - reach                          # the long box's right end
    long_c = end - long_[0] / 2
    cube_c = long_c - float(rng.uniform(0.05, 0.075))
    cy = float(rng.uniform(-0.02, 0.03)) + long_[1] / 2
    columns = [cube_c] + ([cube_c - cube[0] - 0.012] if cube_c - 1.5 * cube[0] > -shelf.width / 2 + GAP else [])
    for cx in columns:
        for _ in range(2):
            p = lay.upright(cube, cx, cube[1] / 2 + float(rng.uniform(-0.02, 0.03)), 0.0, min_support=0.5)
            if p is None:
                return lay.placed
            lay.add(p)
    bridge = lay.upright(long_, long_c, cy, 0.0, min_support=0.2)
    if bridge is None:
        return lay.placed
    lay.add(bridge)
    lean = _leaning_at(lay, end, -1, phi, cy)
    if lean is not None:
        lay.add(lean)
    _drop_rest(lay, rng, n)
    return lay.placed


def _drop_rest(lay: _Layout, rng: np.random.Generator, n: int) -> None:
    """Upright boxes of random types dropped where they land low until there are n (or no room)."""
    types = list(BOX_TYPES.values())
    for _ in range(6 * n):
        if len(lay.placed) >= n:
            return
        t = types[int(rng.integers(len(types)))]
        for cx, cy in _landing_spots(lay, rng, t, 0.0, 8, pile=True):
            p = lay.upright(t, cx, cy, 0.0, min_support=0.4)
            if p is not None and p.position[2] + t[2] / 2 <= lay.shelf.height - 0.05:
                lay.add(p)
                break


def _hard(kind: str, rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    """The stacks where highest-first collapses often (HARD_KINDS)."""
    if kind == "proud":
        return _columns(rng, n, shelf, unstructured=False, proud=0.5)
    if kind == "bridge":
        return _scattered(rng, n, shelf, bridges=3)
    if kind == "lean":
        if rng.random() < 0.6:
            return _leaning_on_overhang(rng, n, shelf)
        return _leaning_on_columns(rng, n, shelf)
    return _columns(rng, n, shelf, unstructured=True)   # overhang: turned, shifted columns at any size


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


def layout(kind: str, seed: int, n_boxes: int | None = None, attempt: int = 0,
           mass_range: tuple[float, float] | None = None) -> Scene:
    """The geometric placement alone (not settled): what `generate` hands to the simulation."""
    if kind not in KINDS:
        raise ShelfpickError(f"kind: expected one of {', '.join(KINDS)}, got {kind!r}")
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, KINDS.index(kind), attempt])
    n = int(rng.integers(8, 15)) if n_boxes is None else int(n_boxes)
    if not 1 <= n <= MAX_BOXES:
        raise ShelfpickError(f"n_boxes: expected 1..{MAX_BOXES}, got {n_boxes!r}")
    if kind in HARD_KINDS:
        placed = _hard(kind, rng, n, SHELF)
    else:
        placed = (_structured if kind == "structured" else _unstructured)(rng, n, SHELF)
    boxes = _order([p.box("_") for p in placed])
    masses = _masses(mass_range, len(boxes), seed, kind, attempt)
    boxes = [Box(f"b{i}", b.size, b.position, b.orientation, m) for i, (b, m) in enumerate(zip(boxes, masses))]
    return Scene(SHELF, tuple(boxes), source={"generator": "shelfpick.shelves", "kind": kind,
                                               "seed": int(seed), "attempt": attempt, "n_boxes": n})


def _masses(mass_range: tuple[float, float] | None, n: int, seed: int, kind: str,
            attempt: int) -> list[float | None]:
    """True masses, uniform in `mass_range` (kg) from their own stream (the layout is the same with
    or without them); None each when no range is given (the method's density decides)."""
    if mass_range is None:
        return [None] * n
    rng = np.random.default_rng([int(seed) & 0xFFFFFFFF, KINDS.index(kind), attempt, 7919])
    return [round(float(m), 3) for m in rng.uniform(mass_range[0], mass_range[1], n)]


def _reload_problem(scene: Scene) -> str:
    """A shelf written is a truth: read back into a fresh simulation it must come to rest where it
    is (a column rocking on a light box can pass the first settle and not the next). '' when it does."""

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            sim = ShelfSim(scene)
        except SceneError as exc:
            return f"read back, it does not stand: {exc}"
    try:
        after = {b.id: b.position for b in sim.scene.boxes}
        gone = set(scene.ids) - set(sim.present())
    finally:
        sim.close()
    moved = max((math.dist(b.position, after[b.id]) for b in scene.boxes if b.id in after), default=0.0)
    if gone or moved > STILL_LIMIT:
        return f"read back, boxes moved {moved * 100:.1f} cm or fell ({sorted(gone)})"
    return ""


def _settle(scene: Scene) -> Scene:
    """Settle in the physics simulation; SceneError if it does not rest or boxes moved far."""

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ShelfSim(scene)
    try:
        settled = sim.scene
        present = set(sim.present())
        drift = sim.idle(STILL_TIME) if present == set(scene.ids) else {}
    finally:
        sim.close()
    creeping = {b: d for b, d in drift.items() if d > STILL_LIMIT}
    if creeping:
        worst = max(creeping, key=creeping.get)
        raise SceneError(f"box {worst} still moves {creeping[worst] * 100:.1f} cm in {STILL_TIME:.0f} s "
                         f"after settling: the shelf is not at rest")
    if present != set(scene.ids):
        raise SceneError(f"boxes fell off while settling: {sorted(set(scene.ids) - present)}")
    after = {b.id: b for b in settled.boxes}
    for b in scene.boxes:
        a = after[b.id]
        # every box was placed GAP above what holds it: a stack of k boxes sinks by about k * GAP
        sink = GAP * (1 + (b.position[2] - b.size[2] / 2) / 0.17)
        side = math.hypot(a.position[0] - b.position[0], a.position[1] - b.position[1])
        drop = b.position[2] - a.position[2]
        move = max(side, abs(drop) - sink if drop > 0 else -drop)
        turn = rot_angle_deg(a.orientation, b.orientation)
        if move > SETTLE_MOVE_LIMIT or turn > SETTLE_TURN_LIMIT:
            raise SceneError(f"box {b.id} moved {move * 100:.1f} cm / {turn:.0f} deg while settling")
        if min(c[2] for c in a.corners()) < -0.01:
            raise SceneError(f"box {b.id} fell below the shelf floor")
    return settled


def generate(kind: str, seed: int, n_boxes: int | None = None, *, settle: bool = True,
             masses: bool | None = None) -> Scene:
    """A settled synthetic shelf, ids b0..bN-1 bottom-up then left to right. Same seed, same scene.

    Attempts whose layout cannot take all the boxes, or which do not settle
    calmly (with their masses), are dropped; the next attempt is derived from the same seed.
    `masses`: true per-box masses drawn in MASS_RANGE; default (None) for the hard kinds only,
    so the structured and unstructured shelves stay what they were.
    """
    with_masses = kind in HARD_KINDS if masses is None else bool(masses)
    mass_range = MASS_RANGE if with_masses else None
    last = ""
    for attempt in range(MAX_ATTEMPTS):
        scene = layout(kind, seed, n_boxes, attempt, mass_range)
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
        mass = {b.id: b.mass for b in scene.boxes}
        rename = [Box(f"b{i}", b.size, b.position, b.orientation, mass[b.id]) for i, b in enumerate(boxes)]
        out = Scene(SHELF, tuple(rename), source=scene.source)
        why = _reload_problem(out)
        if why:
            last = why
            continue
        return out
    raise SceneError(f"no {kind} shelf with {n_boxes} boxes for seed {seed} after "
                     f"{MAX_ATTEMPTS} attempts (last: {last})")
