"""Where two oriented boxes meet when one slides along an axis (the separating-axis sweep).

`make_valid` rests boxes on each other and pushes neighbours apart. On axis-aligned bounds a
box turned about the vertical or leaning sideways is up to 40% larger than itself (a 31x25 cm
face leaning 24 deg spans 38x34 cm), so a neighbour it only comes near reads as "partly inside
it" and is pushed up by 7-20 cm (issue 14, the judge's unstructured shelves). The sweep works on
the boxes' real shapes: for convex bodies the shifts t at which `a + t * d` meets `b` form one
open interval, the intersection over the 15 separating axes of each axis's interval.
"""
from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Iterator

import numpy as np

from shelfpick.perception.scene import Box, quat_to_matrix

# a measured face: the front slab of a box whose depth is a placeholder (the camera sees the
# face only; what lies behind it is unknown and must not move the face)
FACE_SLAB = 0.02


class PoseMemo:
    """What a box's pose gives (its corners, two boxes' separating axes, a box's extents on them
    and a direction's components along them), remembered while one `make_valid` runs
    (`pose_memo`): it sweeps ~200 pairs a frame and a box's extents on one pair's axes four times
    over (30-50 ms of it). Values are computed as without it, and read-only."""

    def __init__(self) -> None:
        self.corners: dict[tuple, np.ndarray] = {}
        self.axes: dict[tuple, tuple[np.ndarray, ...]] = {}
        self.extents: dict[tuple, tuple[list[float], list[float]]] = {}
        self.along: dict[tuple, list[float]] = {}


# the memo of the `make_valid` running in this context (None outside one): a context variable, so
# concurrent calls (a console's threads) never share one
_MEMO: contextvars.ContextVar[PoseMemo | None] = contextvars.ContextVar("shelfpick_pose_memo", default=None)


@contextlib.contextmanager
def pose_memo() -> Iterator[PoseMemo]:
    """Within the body, corners and axes come from one new `PoseMemo`, dropped at the end."""
    memo = PoseMemo()
    token = _MEMO.set(memo)
    try:
        yield memo
    finally:
        _MEMO.reset(token)


def _pose(b: Box) -> tuple:
    """What a box's corners depend on (the memo's key)."""
    return tuple(b.position), tuple(b.size), tuple(b.orientation)


def box_corners(b: Box) -> np.ndarray:
    """`b.corners()` as an 8x3 array (read-only; remembered by pose inside `pose_memo`)."""
    memo = _MEMO.get()
    key = _pose(b)
    hit = memo.corners.get(key) if memo is not None else None
    if hit is None:
        hit = np.asarray(b.corners(), float)
        hit.flags.writeable = False
        if memo is not None:
            memo.corners[key] = hit
    return hit


def _axes(a: Box, b: Box) -> tuple[np.ndarray, ...]:
    """The 15 candidate separating axes of two boxes (face normals and edge crosses; remembered
    by the two orientations inside `pose_memo`)."""
    memo = _MEMO.get()
    key = (tuple(a.orientation), tuple(b.orientation))
    hit = memo.axes.get(key) if memo is not None else None
    if hit is not None:
        return hit
    ra, rb = np.asarray(quat_to_matrix(a.orientation)), np.asarray(quat_to_matrix(b.orientation))
    out = [ra[:, i] for i in range(3)] + [rb[:, i] for i in range(3)]
    for i in range(3):
        for j in range(3):
            c = _cross(ra[:, i], rb[:, j])
            n = float(np.linalg.norm(c))
            if n > 1e-9:
                out.append(c / n)
    for v in out:
        v.flags.writeable = False
    if memo is not None:
        memo.axes[key] = tuple(out)
    return tuple(out)


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """`np.cross` of two 3-vectors in Python floats: numpy's own products and differences, each
    rounded once (the same numbers, without np.cross's ~25 us of broadcasting a call)."""
    u0, u1, u2 = u.tolist()
    v0, v1, v2 = v.tolist()
    return np.array([u1 * v2 - u2 * v1, u2 * v0 - u0 * v2, u0 * v1 - u1 * v0])


def _extents(box: Box, axes: tuple[np.ndarray, ...], key: tuple) -> tuple[list[float], list[float]]:
    """(lows, highs) of the box's corners projected on each of `axes` (`corners @ axis`, an axis
    at a time as `sweep` always did); remembered inside `pose_memo` by the box's pose and `key`
    (the two orientations the axes are of)."""
    memo = _MEMO.get()
    k = (_pose(box), key)
    hit = memo.extents.get(k) if memo is not None else None
    if hit is None:
        c = box_corners(box)
        p = np.array([c @ n for n in axes])
        hit = (p.min(axis=1).tolist(), p.max(axis=1).tolist())
        if memo is not None:
            memo.extents[k] = hit
    return hit


def _along(axes: tuple[np.ndarray, ...], key: tuple, d: np.ndarray) -> list[float]:
    """`float(axis @ d)` for each of `axes`; remembered inside `pose_memo` by `key` and d."""
    memo = _MEMO.get()
    k = (key, tuple(d.tolist()))
    hit = memo.along.get(k) if memo is not None else None
    if hit is None:
        hit = [float(n @ d) for n in axes]
        if memo is not None:
            memo.along[k] = hit
    return hit


def sweep(a: Box, b: Box, direction: tuple[float, float, float]) -> tuple[float, float] | None:
    """(lo, hi): `a` moved by t * direction overlaps `b` exactly for lo < t < hi; None when no
    such shift exists (they pass each other). t = 0 inside the interval: they overlap now."""
    d = np.asarray(direction, float)
    axes = _axes(a, b)
    key = (tuple(a.orientation), tuple(b.orientation))
    (alo, ahi), (blo, bhi) = _extents(a, axes, key), _extents(b, axes, key)
    lo, hi = -np.inf, np.inf
    for a0, a1, b0, b1, nd in zip(alo, ahi, blo, bhi, _along(axes, key, d)):
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
