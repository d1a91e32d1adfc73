"""Quaternion helpers: how far a box leans, whatever it is turned or stood on."""
from __future__ import annotations

import math

import pytest

from shelfpick.perception.scene import quat_to_matrix
from shelfpick.planning.geometry3 import lean_deg


def _about(axis: tuple[float, float, float], deg: float) -> tuple[float, float, float, float]:
    h = math.radians(deg) / 2
    return (math.cos(h), *(a * math.sin(h) for a in axis))


def test_a_tilt_about_a_horizontal_axis_is_the_lean():
    assert lean_deg(quat_to_matrix(_about((1.0, 0.0, 0.0), 12.0))) == pytest.approx(12.0)
    assert lean_deg(quat_to_matrix(_about((0.0, 1.0, 0.0), 7.0))) == pytest.approx(7.0)


def test_a_turn_about_the_vertical_or_a_box_on_another_face_does_not_lean():
    assert lean_deg(quat_to_matrix(_about((0.0, 0.0, 1.0), 35.0))) < 1e-6
    assert lean_deg(quat_to_matrix(_about((1.0, 0.0, 0.0), 90.0))) < 1e-6
    # on its side and turned: still upright
    on_side = quat_to_matrix(_about((0.0, 1.0, 0.0), 90.0))
    turned = quat_to_matrix(_about((0.0, 0.0, 1.0), 20.0))
    r = [[sum(turned[i][k] * on_side[k][j] for k in range(3)) for j in range(3)] for i in range(3)]
    assert lean_deg(r) < 1e-6
