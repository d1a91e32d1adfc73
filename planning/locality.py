"""Which boxes a change at some boxes can move before a step is decided (local trials).

A prediction trial simulates only the pulled box's neighbourhood; every other
box stands in as a static copy of itself (docs/physics.md, "Local trials"). The
neighbourhood is a pure function of the boxes' axis-aligned bounding boxes.
"""
from __future__ import annotations

from typing import Iterable, Mapping

AABB = tuple[tuple[float, float, float], tuple[float, float, float]]


def _near(a: AABB, c: AABB, m: float) -> bool:
    return (a[0][0] - m < c[1][0] and c[0][0] - m < a[1][0] and a[0][1] - m < c[1][1]
            and c[0][1] - m < a[1][1] and a[0][2] - m < c[1][2] and c[0][2] - m < a[1][2])


def _in_front(a: AABB, c: AABB, m: float) -> bool:
    """`c` overlaps `a` in x and z (within m) and starts in front of it (smaller y)."""
    return (a[0][0] - m < c[1][0] and c[0][0] - m < a[1][0] and a[0][2] - m < c[1][2]
            and c[0][2] - m < a[1][2] and c[0][1] < a[0][1])


def stands_on(c: AABB, d: AABB, overlap: float, tilt: float, margin: float) -> bool:
    """`c`'s bottom is at `d`'s top (`tilt` below to `margin` above) and their footprints overlap.

    Bounding boxes of turned or leaning boxes overlap in z where the boxes only touch: a
    bottom anywhere above `d`'s middle still counts (a box left frozen on top of a moving
    one would pin it in place)."""
    ov = overlap
    low = min(d[1][2] - tilt, 0.5 * (d[0][2] + d[1][2]))
    return (c[0][0] < d[1][0] - ov and d[0][0] < c[1][0] - ov and c[0][1] < d[1][1] - ov
            and d[0][1] < c[1][1] - ov and low < c[0][2] < d[1][2] + margin)


def neighbourhood(box: Mapping[str, AABB], seeds: Iterable[str], *, margin: float, overlap: float,
                  tilt: float, corridor: bool = False) -> set[str]:
    """The boxes of `box` (id -> AABB, in shelf order) a change at `seeds` can move.

    - the seeds and every box whose bounding box comes within `margin` of a seed's;
    - with `corridor` (a pull), every box in front of a seed that overlaps it in x
      and z (within the margin): the box and the gripper travel there;
    - what the seeds stand on, down to the floor (a fragile column under the pulled
      box rocks with it);
    - everything stacked on any of those, up to the top;
    - the direct supports of all of those (a box bridging two columns pivots on both).

    The rest of the shelf can only move once some box here has moved a lot, and by
    then the step has collapsed.
    """
    seeds = list(seeds)
    act = list(box)
    keep = {s for s in seeds if s in box}

    def on(c: str, d: str) -> bool:
        return stands_on(box[c], box[d], overlap, tilt, margin)

    seed_boxes = [box[s] for s in keep]
    keep |= {c for c in act if any(_near(a, box[c], margin) or (corridor and _in_front(a, box[c], margin))
                                   for a in seed_boxes)}
    down = set(keep & set(seeds))
    todo = list(down)
    while todo:
        c = todo.pop()
        for d in act:
            if d not in down and on(c, d):
                down.add(d)
                todo.append(d)
    keep |= down
    todo = [b for b in act if b in keep]
    while todo:
        d = todo.pop()
        for c in act:
            if c not in keep and on(c, d):
                keep.add(c)
                todo.append(c)
    keep |= {d for d in act if d not in keep and any(on(c, d) for c in keep)}
    return keep
