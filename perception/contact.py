"""Where two oriented boxes meet when one slides along an axis (the separating-axis sweep).

`make_valid` rests boxes on each other and pushes neighbours apart. On axis-aligned bounds a
box turned about the vertical or leaning sideways is up to 40% larger than itself (a 31x25 cm
face leaning 24 deg spans 38x34 cm), so a neighbour it only comes near reads as "partly inside
it" and is pushed up by 7-20 cm (issue 14, the judge's unstructured shelves). The sweep works on
the boxes' real shapes: for convex bodies the shifts t at which `a + t * d` meets `b` form one
open interval, the intersection over the 15 separating axes of each axis's interval.
"""
from __future__ import annotations

import numpy as np

from shelfpick.perception.scene import Box, quat_to_matrix

# a measured face: the front slab of a box whose depth is a placeholder (the camera sees the
# face only; what lies behind it is unknown and must not move the face)
FACE_SLAB = 0.02


# memos of what a box's pose gives (make_valid asks for the same boxes' corners and axes
# thousands of times a frame: 30-50 ms of it); values are computed as before and read-only
_MEMO_MAX = 4096
_CORNERS: dict[tuple, np.ndarray] = {}
_AXES: dict[tuple, tuple[np.ndarray, ...]] = {}


def _pose_key(b: Box) -> tuple:
    return tuple(b.position), tuple(b.size), tuple(b.orientation)


def _remember(memo: dict, key: tuple, value):
    if len(memo) >= _MEMO_MAX:
        memo.clear()
    memo[key] = value
    return value


def box_corners(b: Box) -> np.ndarray:
    """`b.corners()` as an 8x3 array (read-only, memoised by pose)."""
    key = _pose_key(b)
    hit = _CORNERS.get(key)
    if hit is None:
        hit = np.asarray(b.corners(), float)
        hit.flags.writeable = False
        _remember(_CORNERS, key, hit)
    return hit


def _axes(a: Box, b: Box) -> tuple[np.ndarray, ...]:
    """The 15 candidate separating axes of two boxes (face normals and edge crosses; memoised
    by the two orientations)."""
    key = (tuple(a.orientation), tuple(b.orientation))
    hit = _AXES.get(key)
    if hit is not None:
        return hit
    ra, rb = np.asarray(quat_to_matrix(a.orientation)), np.asarray(quat_to_matrix(b.orientation))
    out = [ra[:, i] for i in range(3)] + [rb[:, i] for i in range(3)]
    for i in range(3):
        for j in range(3):
            c = np.cross(ra[:, i], rb[:, j])
            n = float(np.linalg.norm(c))
            if n > 1e-9:
                out.append(c / n)
    for v in out:
        v.flags.writeable = False
    return _remember(_AXES, key, tuple(out))


def sweep(a: Box, b: Box, direction: tuple[float, float, float]) -> tuple[float, float] | None:
    """(lo, hi): `a` moved by t * direction overlaps `b` exactly for lo < t < hi; None when no
    such shift exists (they pass each other). t = 0 inside the interval: they overlap now."""
    d = np.asarray(direction, float)
    ca, cb = box_corners(a), box_corners(b)
    lo, hi = -np.inf, np.inf
    for n in _axes(a, b):
        pa, pb = ca @ n, cb @ n
        a0, a1, b0, b1 = pa.min(), pa.max(), pb.min(), pb.max()
        nd = float(n @ d)
        if abs(nd) < 1e-9:
            if a0 >= b1 - 1e-9 or b0 >= a1 - 1e-9:
                return None
            continue
        t0, t1 = (b0 - a1) / nd, (b1 - a0) / nd
        if t0 > t1:
            t0, t1 = t1, t0
        lo, hi = max(lo, t0), min(hi, t1)
        if lo >= hi:
            return None
    return float(lo), float(hi)


def face_part(b: Box) -> Box:
    """What the camera measured of a box: all of it when its depth is known, else its front slab."""
    if b.depth_known:
        return b
    return b.with_depth(min(b.size[1], FACE_SLAB))


def face_sweep(a: Box, b: Box, direction: tuple[float, float, float]) -> tuple[float, float] | None:
    """`sweep` counting only contacts that involve a measured face: a's face against b, or a
    against b's face (the union of the two intervals' hulls); None when neither meets."""
    got = [s for s in (sweep(face_part(a), b, direction), sweep(a, face_part(b), direction)) if s is not None]
    if not got:
        return None
    return min(s[0] for s in got), max(s[1] for s in got)
