"""Small 3-vector and quaternion helpers on plain floats (faster than numpy for one vector)."""
from __future__ import annotations

import math


def rot_angle_deg(q0: tuple, q1: tuple) -> float:
    """Angle (degrees) between two unit quaternions (any order convention, the same for both)."""
    d = abs(q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3])
    return math.degrees(2.0 * math.acos(min(1.0, d)))


def lean_deg(r: list[list[float]]) -> float:
    """How far the most vertical axis of rotation matrix `r` is from the vertical, in degrees: 0 for
    any turn about the vertical and for a box standing on any of its faces."""
    return math.degrees(math.acos(min(1.0, max(abs(r[2][0]), abs(r[2][1]), abs(r[2][2])))))


def dist(a: tuple, b: tuple) -> float:
    return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)


def norm(v: tuple) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def matvec(r: list[list[float]], v: tuple) -> tuple[float, float, float]:
    return (r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2])
