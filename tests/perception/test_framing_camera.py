"""benchmarks/perceive_plan.py's framing camera: a deployment points the camera so the stack is
in view; the default camera (1.05 m back, 0.8 m up) does not see a tall stack's top."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.geometry import project
from shelfpick.perception.render import default_camera
from shelfpick.perception.scene import Scene, Shelf
from synth_frames import box

from benchmarks import perceive_plan as pp


def _tall() -> Scene:
    """Two columns; the left one stacks to 1.3 m, the right one is a single cube."""
    return Scene(Shelf(1.0, 0.30, 1.60), (box("a", -0.25, 0.0, 0.31, 0.80, d=0.23),
                                          box("b", -0.25, 0.80, 0.17, 0.50, d=0.17),
                                          box("c", 0.30, 0.0, 0.20, 0.20, d=0.20, front=0.05)))


def test_default_camera_misses_the_top_of_a_tall_stack() -> None:
    assert pp.out_of_view(_tall(), default_camera()) == ["b"]


def test_framing_camera_has_every_front_corner_inside_with_margin() -> None:
    sc = _tall()
    cam = pp.framing_camera(sc)
    assert cam.position[0] == 0.0 and cam.position[1] < default_camera().position[1]
    assert pp.out_of_view(sc, cam, pp.FRAME_MARGIN_PX) == []
    uv, z = project(cam, pp.front_corners(sc))
    assert (z > 0).all()
    # pitched to centre the stack: top and bottom slack within a few pixels of each other
    top, bottom = uv[:, 1].min(), cam.height - 1 - uv[:, 1].max()
    assert abs(top - bottom) < 2.0
    # and no further back than needed: one step closer, a corner leaves the margin
    y = cam.position[1] + pp.FRAME_STEP
    assert all(pp.out_of_view(sc, pp._pitched(cam, y, cam.position[2], p), pp.FRAME_MARGIN_PX)
               for p in np.linspace(-20.0, 40.0, 121))


def test_a_low_shelf_keeps_the_default_distance() -> None:
    sc = Scene(Shelf(), (box("a", 0.0, 0.0, 0.31, 0.25, d=0.23),))
    assert pp.framing_camera(sc).position[1] == default_camera().position[1]
