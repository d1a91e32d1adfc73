"""Columns of one box type stacked bottom-up (structured, dense unstructured, proud and overhang
shelves): the column types and their x spans, and each box placed on its column."""
from __future__ import annotations

import math

import numpy as np

from shelfpick.perception.scene import BOX_TYPES, Shelf
from shelfpick.planning.shelves.placement import (
    FRONT_MAX,
    FRONT_MIN,
    GAP,
    PROUD_RANGE,
    STANDING_LONG,
    _cap,
    _extent,
    _Layout,
    _Placed,
    _room,
)


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
