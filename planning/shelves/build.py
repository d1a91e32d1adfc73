"""A shelf of a kind from a seed: the layout (attempt by attempt, same seed, same scene), its true
masses, and `generate`, which keeps the first attempt that takes all boxes and settles calmly."""
from __future__ import annotations

from typing import Literal

import numpy as np

from shelfpick.perception.errors import SceneError, ShelfpickError
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.shelves.columns import _columns
from shelfpick.planning.shelves.hard import _hard
from shelfpick.planning.shelves.piles import _scattered
from shelfpick.planning.shelves.placement import DENSE_FROM, SHELF, _Placed
from shelfpick.planning.shelves.settle import _reload_problem, _settle

Kind = Literal["structured", "unstructured", "proud", "bridge", "lean", "overhang"]
# the last four are stacks where the highest-first baseline collapses often (docs/bench.md):
# boxes proud of the front carrying others, long boxes bridging two supports, boxes leaning on a
# stack, boxes turned and shifted over the one below
KINDS: tuple[str, ...] = ("structured", "unstructured", "proud", "bridge", "lean", "overhang")
HARD_KINDS: tuple[str, ...] = KINDS[2:]
MASS_RANGE = (0.3, 5.0)              # kg, true masses drawn per box (the hard kinds; --masses)
MAX_BOXES = 30
MAX_ATTEMPTS = 60


def _unstructured(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    """Small scenes: random piles; dense ones (more than 16 boxes): turned, shifted columns."""
    if n <= DENSE_FROM:
        return _scattered(rng, n, shelf)
    return _columns(rng, n, shelf, unstructured=True)


def _structured(rng: np.random.Generator, n: int, shelf: Shelf) -> list[_Placed]:
    return _columns(rng, n, shelf, unstructured=False)


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
