"""The rigid shelf-to-robot-base transform a grasp is sent in (and a robot maps back through)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping, Sequence

from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import quat_to_matrix, read_json

Vec3 = tuple[float, float, float]


@dataclass(frozen=True)
class Transform:
    """Rigid shelf-to-robot-base transform: p_robot = R @ p_shelf + t (metres)."""

    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    translation: Vec3 = (0.0, 0.0, 0.0)

    @classmethod
    def identity(cls) -> "Transform":
        return cls()

    @classmethod
    def from_pose(cls, position: Sequence[float], wxyz: Sequence[float]) -> "Transform":
        n = math.sqrt(sum(float(c) * float(c) for c in wxyz))
        if not 0.999 <= n <= 1.001:
            raise FormatError("", "orientation", f"quaternion (w, x, y, z) is not unit length (|q|={n:.4f})")
        r = quat_to_matrix([float(c) / n for c in wxyz])
        return cls(tuple(tuple(float(v) for v in row) for row in r), tuple(float(v) for v in position))

    @classmethod
    def from_json(cls, doc: Any, origin: str = "") -> "Transform":
        """`{"matrix": 4x4}` or `{"position": [x,y,z], "orientation": [w,x,y,z]}` (shelf pose in robot base)."""
        if not isinstance(doc, Mapping):
            raise FormatError(origin, "transform", f"expected an object, got {type(doc).__name__}")
        if "matrix" in doc:
            m = doc["matrix"]
            if (not isinstance(m, list) or len(m) != 4
                    or not all(isinstance(r, list) and len(r) == 4 for r in m)
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                               for r in m for v in r)):
                raise FormatError(origin, "matrix", f"expected 4 rows of 4 numbers, got {m!r}")
            if [float(v) for v in m[3]] != [0.0, 0.0, 0.0, 1.0]:
                raise FormatError(origin, "matrix[3]", f"last row must be [0, 0, 0, 1], got {m[3]!r}")
            rot = tuple(tuple(float(v) for v in m[i][:3]) for i in range(3))
            t = cls(rot, tuple(float(m[i][3]) for i in range(3)))
        elif "position" in doc or "orientation" in doc:
            pos = doc.get("position", [0.0, 0.0, 0.0])
            quat = doc.get("orientation", [1.0, 0.0, 0.0, 0.0])
            for name, v, n in (("position", pos, 3), ("orientation", quat, 4)):
                if (not isinstance(v, list) or len(v) != n
                        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                                   for x in v)):
                    raise FormatError(origin, name, f"expected a list of {n} numbers, got {v!r}")
            norm = math.sqrt(sum(c * c for c in quat))
            if abs(norm - 1.0) > 1e-3:
                raise FormatError(origin, "orientation", f"quaternion (w, x, y, z) is not unit length "
                                  f"(|q|={norm:.4f}): {quat!r}")
            t = cls.from_pose(pos, [c / norm for c in quat])
        else:
            raise FormatError(origin, "transform", "expected 'matrix' or 'position'/'orientation'")
        t.check(origin)
        return t

    @classmethod
    def load(cls, path: str | Path) -> "Transform":
        return cls.from_json(read_json(path), str(path))

    def check(self, origin: str = "") -> None:
        r = self.rotation
        for i in range(3):
            for j in range(3):
                dot = sum(r[k][i] * r[k][j] for k in range(3))
                if abs(dot - (1.0 if i == j else 0.0)) > 1e-4:
                    raise FormatError(origin, "matrix", "rotation part is not orthonormal")
        det = (r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
               + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]))
        if det < 0:
            raise FormatError(origin, "matrix", "rotation part is a reflection (determinant -1)")

    def direction(self, v: Sequence[float]) -> Vec3:
        r = self.rotation
        return tuple(r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2] for i in range(3))  # type: ignore

    def point(self, p: Sequence[float]) -> Vec3:
        d = self.direction(p)
        return tuple(d[i] + self.translation[i] for i in range(3))  # type: ignore[return-value]

    def inverse(self) -> "Transform":
        rt = tuple(tuple(self.rotation[j][i] for j in range(3)) for i in range(3))
        inv = Transform(rt, (0.0, 0.0, 0.0))
        t = inv.direction(self.translation)
        return Transform(rt, (-t[0], -t[1], -t[2]))

    def matrix(self) -> list[list[float]]:
        return [list(self.rotation[i]) + [self.translation[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]

    def to_json(self) -> dict:
        return {"matrix": self.matrix()}


__all__ = ["Transform", "Vec3"]
