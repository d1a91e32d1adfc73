"""The baseline planner: remove boxes highest first, no physics involved.

This is what the method compares against: sort the boxes by the height of
their top (highest first) and take them out in that order until the target
is out (extract) or the shelf is empty (clear).
"""
from __future__ import annotations

from shelfpick.perception.scene import Scene


def height_key(box) -> tuple:
    """Highest top first; ties (to the millimetre) left to right, then by id."""
    return (-round(box.top_z, 3), round(box.position[0], 3), box.id)


def heuristic_order(scene: Scene, target: str | None) -> tuple[str, ...]:
    """Removal order of the baseline: the whole sorted list, or its prefix ending at ``target``."""
    order = tuple(b.id for b in sorted(scene.boxes, key=height_key))
    if target is None:
        return order
    scene.require(target)
    return order[: order.index(target) + 1]
