"""Random piles (small unstructured and bridge shelves): boxes dropped where they land low, long
boxes bridging two tops, standing long boxes leaning on a wall or a stack."""
from __future__ import annotations

import math

import numpy as np

from shelfpick.perception.scene import BOX_TYPES, Shelf, quat_to_matrix
from shelfpick.planning.shelves.placement import (
    CELL,
    FRONT_MAX,
    FRONT_MIN,
    GAP,
    SHELF,
    STANDING_LONG,
    _axis_quat,
    _extent,
    _Layout,
    _Placed,
)


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
