"""Small seeded sampler of shelf scenes for the perception benchmark and tests.

Perception may not import planning, so the benchmark has its own generator:
columns of stacked boxes (the method's three box types, any face to the
front that fits the shelf depth) standing on the floor, fronts aligned
(structured) or scattered in depth with gaps (unstructured). Geometric only:
every box rests flat on the floor or on the box below, nothing overlaps.
"""
from __future__ import annotations

import itertools

import numpy as np

from perception.scene import BOX_TYPES as TYPE_TABLE
from perception.scene import Box, Scene, Shelf

BOX_TYPES = tuple(TYPE_TABLE.values())


def _orientations(size: tuple[float, float, float], shelf: Shelf) -> list[tuple[float, float, float]]:
    out = []
    for p in set(itertools.permutations(size)):
        if p[1] <= shelf.depth - 0.01:
            out.append(p)
    return sorted(out)


def sample_scene(seed: int, kind: str = "structured", n_boxes: int = 10, shelf: Shelf | None = None,
                 max_height: float = 0.80) -> Scene:
    """A seeded scene of up to `n_boxes` boxes; same seed, same scene."""
    shelf = shelf or Shelf()
    rng = np.random.default_rng(seed)
    boxes: list[Box] = []
    x = -shelf.width / 2 + float(rng.uniform(0.0, 0.03))
    while len(boxes) < n_boxes:
        t = BOX_TYPES[int(rng.integers(len(BOX_TYPES)))]
        opts = _orientations(t, shelf)
        w, d, h = opts[int(rng.integers(len(opts)))]
        if x + w > shelf.width / 2:
            break
        cx = x + w / 2
        z = 0.0
        front = 0.0 if kind == "structured" else float(rng.uniform(0.0, shelf.depth - d))
        boxes.append(Box(f"b{len(boxes)}", (w, d, h), (cx, front + d / 2, h / 2)))
        base_w = w
        z = h
        # stack on top: narrower or equal boxes, centred over the support
        while len(boxes) < n_boxes and rng.random() < 0.9:
            cand = [o for t2 in BOX_TYPES for o in _orientations(t2, shelf)
                    if o[0] <= w + 1e-9 and z + o[2] <= max_height]
            if not cand:
                break
            w2, d2, h2 = cand[int(rng.integers(len(cand)))]
            off = float(rng.uniform(-(w - w2) / 2, (w - w2) / 2)) if kind != "structured" else 0.0
            front2 = front if kind == "structured" else float(np.clip(front + rng.uniform(-0.03, 0.03),
                                                                      0.0, shelf.depth - d2))
            boxes.append(Box(f"b{len(boxes)}", (w2, d2, h2), (cx + off, front2 + d2 / 2, z + h2 / 2)))
            z += h2
            w = w2
        gap = 0.01 if kind == "structured" else float(rng.uniform(0.005, 0.05))
        x = cx + base_w / 2 + gap
    return Scene(shelf, tuple(boxes), None, {"kind": "perception-bench", "layout": kind, "seed": seed})
