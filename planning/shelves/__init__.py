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

One idea a module: `placement` (the height map, overlap and support tests),
`columns` (column stacks), `piles` (random piles, bridges, leaning boxes),
`hard` (the HARD_KINDS stacks), `settle` (physics settling and the read-back
check), `build` (`layout` and `generate`). Names with a leading underscore are
shared inside this package only (`_Placed` and `_reload_problem` are
re-exported here for the tests).
"""
from __future__ import annotations

from shelfpick.perception.scene import BOX_TYPES
from shelfpick.planning.shelves.build import (
    HARD_KINDS,
    KINDS,
    MASS_RANGE,
    MAX_ATTEMPTS,
    MAX_BOXES,
    Kind,
    generate,
    layout,
)
from shelfpick.planning.shelves.placement import (
    CELL,
    DENSE_FROM,
    FRONT_MAX,
    FRONT_MIN,
    GAP,
    PROUD_RANGE,
    SHELF,
    STANDING_LONG,
    Y_MIN_GRID,
    obb_overlap,
)
from shelfpick.planning.shelves.placement import _Placed as _Placed  # tests
from shelfpick.planning.shelves.settle import (
    SETTLE_MOVE_LIMIT,
    SETTLE_TURN_LIMIT,
    STILL_LIMIT,
    STILL_TIME,
)
from shelfpick.planning.shelves.settle import _reload_problem as _reload_problem  # tests

__all__ = ["BOX_TYPES", "CELL", "DENSE_FROM", "FRONT_MAX", "FRONT_MIN", "GAP", "HARD_KINDS", "KINDS", "MASS_RANGE",
           "MAX_ATTEMPTS", "MAX_BOXES", "PROUD_RANGE", "SETTLE_MOVE_LIMIT", "SETTLE_TURN_LIMIT", "SHELF",
           "STANDING_LONG", "STILL_LIMIT", "STILL_TIME", "Y_MIN_GRID", "Kind", "generate", "layout", "obb_overlap"]
