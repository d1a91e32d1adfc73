"""The face error a scene shows by itself: faces that should touch their supports, and do not."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from perception.scene import Box, Scene, Shelf
from planning.face_precision import (EXACT, fit_to_scene, measured_face_error, outline,
                                     support_residuals, vertical_gap)
from planning.planner import make_plan
from planning.uncertainty import Uncertainty


def _face(bid: str, x: float, z_bottom: float, w: float, h: float, tilt_deg: float = 0.0) -> Box:
    """A face seen by the camera (depth unknown, 10 cm placeholder), `tilt_deg` turned in its plane."""
    t = math.radians(tilt_deg)
    q = (math.cos(t / 2), 0.0, math.sin(t / 2), 0.0)   # about y, the face's normal
    zc = z_bottom + (w / 2) * abs(math.sin(t)) + (h / 2) * math.cos(t)
    return Box(bid, (w, 0.10, h), (x, 0.05, zc), q, depth_known=False)


def _column(lifts: tuple[float, ...]) -> Scene:
    """Cubes of 20 cm stacked on the floor, each measured `lifts[i]` above the face under it."""
    boxes, z = [], 0.0
    for i, lift in enumerate(lifts):
        boxes.append(_face(f"b{i}", 0.0, z + lift, 0.20, 0.20))
        z += lift + 0.20
    return Scene(Shelf(), tuple(boxes))


def test_exact_faces_show_no_error_and_draw_none():
    scene = _column((0.0, 0.0, 0.0))
    assert support_residuals(scene) == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    fitted = fit_to_scene(Uncertainty(), scene)
    assert (fitted.face_size_error, fitted.face_depth_error, fitted.fit_faces) == (0.0, 0.0, False)


def test_faces_off_their_supports_show_the_median_gap():
    # each box measured 8 mm off the one it rests on (up or down): that is the error shown
    scene = _column((0.008, -0.008, 0.008))
    assert measured_face_error(scene) == pytest.approx(0.008, abs=1e-6)
    fitted = fit_to_scene(Uncertainty(), scene)
    # drawn up to the in-plane face error (5 mm), not more
    assert fitted.face_size_error == fitted.face_depth_error == Uncertainty().face_error
    three_mm = fit_to_scene(Uncertainty(), _column((0.003, 0.003, -0.003)))
    assert three_mm.face_size_error == pytest.approx(0.003, abs=1e-6)


def test_a_face_on_a_tilted_support_touches_its_slanted_top_edge():
    # a long box tilted 5 deg on the floor, a cube resting on the high end of its top edge
    t = math.radians(5.0)
    low = _face("long", 0.0, 0.0, 0.50, 0.17, tilt_deg=5.0)
    top_at = (0.17 / 2) * math.cos(t) + 0.25 * math.sin(t) + 0.17 / (2 * math.cos(t)) + 0.1 * math.tan(t)
    cube = _face("cube", 0.0, top_at, 0.20, 0.20)
    assert vertical_gap(outline(cube), outline(low)) == pytest.approx(0.0, abs=1e-9)
    # the support's highest corner is more than a centimetre above where the cube rests on it
    assert max(z for _, z in outline(low)) - top_at > 0.01
    assert measured_face_error(Scene(Shelf(), (low, cube))) < EXACT


def test_faces_that_share_too_little_width_do_not_carry_each_other():
    a = _face("a", -0.10, 0.0, 0.20, 0.20)
    b = _face("b", 0.095, 0.20, 0.20, 0.20)   # 1 cm of shared width
    assert vertical_gap(outline(b), outline(a)) is None
    assert vertical_gap(outline(b), outline(_face("c", 0.0, 0.0, 0.20, 0.20))) == pytest.approx(0.0, abs=1e-9)


def test_known_shelves_and_given_errors_are_left_as_they_are():
    noisy = _column((0.008, -0.008, 0.008))
    known = noisy.with_boxes([replace(b, depth_known=True) for b in noisy.boxes])
    assert fit_to_scene(Uncertainty(), known).face_size_error == 0.0
    given = replace(Uncertainty(), face_size_error=0.02, fit_faces=False)
    assert fit_to_scene(given, noisy) is given
    assert fit_to_scene(Uncertainty.none(), noisy).face_size_error == 0.0


def test_the_plan_records_the_face_error_it_drew():
    exact = make_plan(_column((0.0, 0.0)), "extract", "b1", samples=2, verify=0)
    noisy = make_plan(_column((0.004, -0.004)), "extract", "b1", samples=2, verify=0)
    assert exact.extra["search"]["uncertainty"]["face_size_error_m"] == 0.0
    assert noisy.extra["search"]["uncertainty"]["face_size_error_m"] == pytest.approx(0.004, abs=1e-6)
    assert noisy.extra["search"]["uncertainty"]["fit_faces"] is False
