"""The stacks where the highest-first baseline collapses often (HARD_KINDS, docs/bench.md): proud
columns, bridges, a long box leaning on a box that reaches above it, turned and shifted columns."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from shelfpick.perception.scene import BOX_TYPES, Shelf
from shelfpick.planning.shelves.columns import _columns
from shelfpick.planning.shelves.piles import (
    _landing_spots,
    _lean,
    _lean_on_stack,
    _leaning_at,
    _scattered,
)
from shelfpick.planning.shelves.placement import GAP, STANDING_LONG, _Layout, _Placed

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
