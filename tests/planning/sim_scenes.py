"""Tiny scenes built in code for the simulation tests (shared by the sim/predict/execute tests)."""
from __future__ import annotations

from shelfpick.perception.scene import Box, Scene, Shelf

CUBE = (0.2, 0.2, 0.2)


def cube(bid: str, x: float, z: float, y: float = 0.12, size=CUBE) -> Box:
    return Box(bid, size, (x, y, z))


def stacked() -> Scene:
    """`b` stands on `a`; `c` stands alone."""
    return Scene(Shelf(), (cube("a", 0.0, 0.1), cube("b", 0.0, 0.3), cube("c", 0.4, 0.1)))


def column(n: int = 6) -> Scene:
    """A column of n cubes and one free-standing cube `f`."""
    return Scene(Shelf(), tuple(cube(f"c{i}", 0.0, 0.1 + 0.2 * i) for i in range(n)) + (cube("f", 0.35, 0.1),))


def grid(nx: int = 4, nz: int = 3) -> Scene:
    """nx columns of nz cubes, touching side by side, fronts staggered by up to 2 cm."""
    boxes = []
    for i in range(nx):
        for j in range(nz):
            boxes.append(cube(f"b{len(boxes)}", -0.3 + 0.2 * i, 0.1 + 0.2 * j, 0.12 + 0.01 * ((i + j) % 3)))
    return Scene(Shelf(), tuple(boxes))


def twelve() -> Scene:
    """A 12-box shelf like the synthetic structured ones (the one the timing script measures)."""
    from benchmarks.sim_timing import twelve_box_scene

    return twelve_box_scene()
