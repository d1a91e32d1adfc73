"""Camera geometry shared by the perception stages: pixels <-> shelf frame.

The camera pose in `Camera` is camera-to-shelf (OpenCV camera frame: x right,
y down, z forward). Everything here is vectorised numpy so a 640x480 frame
costs a few milliseconds.
"""
from __future__ import annotations

import contextlib
import contextvars
import math
from collections.abc import Iterator

import numpy as np

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.scene import Camera, quat_to_matrix


def pose_matrix(camera: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Rotation (3x3) and translation (3,) taking camera-frame points to the shelf frame."""
    return np.asarray(quat_to_matrix(camera.orientation), dtype=np.float64), \
        np.asarray(camera.position, dtype=np.float64)


def check_intrinsics(camera: Camera, shape: tuple[int, int], origin: str = "camera") -> None:
    """Refuse intrinsics that cannot belong to an image of this size."""
    h, w = shape
    if (camera.width, camera.height) != (w, h):
        raise PerceptionError(f"{origin}: camera is {camera.width}x{camera.height} but the image is {w}x{h}")
    if not 0.0 <= camera.cx <= w:
        raise PerceptionError(f"{origin}: cx={camera.cx:g} lies outside the {w}-pixel-wide image")
    if not 0.0 <= camera.cy <= h:
        raise PerceptionError(f"{origin}: cy={camera.cy:g} lies outside the {h}-pixel-high image")
    for name, f, size in (("fx", camera.fx, w), ("fy", camera.fy, h)):
        fov = math.degrees(2 * math.atan(size / (2 * f)))
        if not 5.0 <= fov <= 170.0:
            raise PerceptionError(f"{origin}: {name}={f:g} gives a {fov:.1f} deg field of view "
                                  f"for {size} pixels (intrinsics do not match the image)")


def pixel_rays(camera: Camera, us: np.ndarray, vs: np.ndarray) -> np.ndarray:
    """Camera-frame rays (z = 1) through pixel coordinates."""
    x = (np.asarray(us, dtype=np.float64) - camera.cx) / camera.fx
    y = (np.asarray(vs, dtype=np.float64) - camera.cy) / camera.fy
    if x.shape != y.shape:
        return np.stack([x, y, np.ones_like(x)], axis=-1)     # numpy's error
    out = np.empty(x.shape + (3,))      # np.stack's array, written a column at a time (2x faster)
    out[..., 0], out[..., 1], out[..., 2] = x, y, 1.0
    return out


def columnwise(a: np.ndarray, op: np.ufunc, b, out: np.ndarray | None = None, *,
               by_row: bool = False) -> np.ndarray:
    """`op(a, b)` of an (..., 3) array `a` and three values `b`, one a column (`by_row`: `op(a,
    b[..., None])`, one value a row), a column at a time into `out` (`a` itself when None, its dtype
    kept): the same values, where numpy's broadcast over a last axis of 3 takes 3-6x as long."""
    out = a if out is None else out
    for j in range(3):
        op(a[..., j], b if by_row else b[j], out=out[..., j])
    return out


def offsets(points: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """`points - origin` of (N, 3) points and one point, a new array made a column at a time
    (`columnwise`)."""
    return columnwise(points, np.subtract, origin, np.empty(points.shape, np.result_type(points, origin)))


def backproject(camera: Camera, us: np.ndarray, vs: np.ndarray, z: np.ndarray) -> np.ndarray:
    """Shelf-frame points (N,3) of pixels (us, vs) at camera z-depth z."""
    rot, t = pose_matrix(camera)
    rays, z = pixel_rays(camera, us, vs), np.asarray(z, dtype=np.float64)
    pc = columnwise(rays, np.multiply, z, by_row=True) if z.shape == rays.shape[:-1] else rays * z[..., None]
    return columnwise(pc @ rot.T, np.add, t)


class PointCache:
    """The last full frame's shelf-frame points, owned by one `perceive` call (`points_cached`).

    Why: one `perceive` asks for the same frame's points three or four times (the segmenter's face
    gate, the shelf-volume test, the unexplained matter), 12 ms each. A hit needs an equal camera
    and a depth image equal in type and every value, so it returns what computing would; the
    points handed out are read-only."""

    def __init__(self) -> None:
        self._last: tuple | None = None      # (camera, a copy of its depth, the points)

    def points(self, camera: Camera, depth: np.ndarray) -> np.ndarray:
        """`point_map` of this frame, computed once while the frame stays the same."""
        last = self._last
        if last is not None and last[0] == camera and last[1].dtype == depth.dtype \
                and np.array_equal(last[1], depth, equal_nan=depth.dtype.kind in "fc"):
            return last[2]
        out = _points(camera, depth)
        out.flags.writeable = False
        self._last = (camera, np.array(depth, copy=True), out)
        return out


# the cache of the `perceive` call running in this context (None outside one): a context variable,
# so two threads' (or a console's concurrent) perceive calls never share one
_CACHE: contextvars.ContextVar[PointCache | None] = contextvars.ContextVar("shelfpick_point_cache", default=None)


@contextlib.contextmanager
def points_cached() -> Iterator[PointCache]:
    """Within the body (one `perceive`), full frames' `point_map`s come from one new `PointCache`,
    dropped at the end."""
    cache = PointCache()
    token = _CACHE.set(cache)
    try:
        yield cache
    finally:
        _CACHE.reset(token)


def point_map(camera: Camera, depth: np.ndarray) -> np.ndarray:
    """HxWx3 shelf-frame points for every pixel (garbage where depth is 0); a full frame's inside
    `points_cached` come from its cache (read-only)."""
    cache = _CACHE.get()
    if cache is not None and depth.shape == (camera.height, camera.width):
        return cache.points(camera, depth)
    return _points(camera, depth)


def _points(camera: Camera, depth: np.ndarray) -> np.ndarray:
    """`point_map` computed."""
    h, w = depth.shape
    vs, us = np.arange(h)[:, None], np.arange(w)[None, :]    # as np.mgrid's, broadcast
    rot, t = pose_matrix(camera)
    rot = rot.astype(np.float32)
    ku = ((us - camera.cx) / camera.fx).astype(np.float32)
    kv = ((vs - camera.cy) / camera.fy).astype(np.float32)
    if depth.dtype == np.float32:       # np.stack's HxWx3 array, its columns written in place
        pc = np.empty((h, w, 3), np.float32)
        np.multiply(ku, depth, out=pc[..., 0])
        np.multiply(kv, depth, out=pc[..., 1])
        pc[..., 2] = depth
    else:
        pc = np.stack([ku * depth, kv * depth, depth.astype(np.float32)], axis=-1)
    out = pc @ rot.T
    out += t.astype(np.float32)
    return out


def project(camera: Camera, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N,2) and camera z (N,) of shelf-frame points."""
    rot, t = pose_matrix(camera)
    pc = (np.asarray(points, dtype=np.float64) - t) @ rot
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u = camera.fx * pc[:, 0] / z + camera.cx
        v = camera.fy * pc[:, 1] / z + camera.cy
    return np.stack([u, v], axis=1), z


def ray_plane(camera: Camera, us: np.ndarray, vs: np.ndarray, point: np.ndarray,
              normal: np.ndarray) -> np.ndarray:
    """Where the pixel rays meet a plane (shelf frame), N x 3; NaN for rays parallel to it."""
    rot, t = pose_matrix(camera)
    dirs = pixel_rays(camera, us, vs) @ rot.T
    denom = dirs @ normal
    with np.errstate(divide="ignore", invalid="ignore"):
        s = ((point - t) @ normal) / denom
    s = np.where(np.abs(denom) < 1e-9, np.nan, s)
    return columnwise(columnwise(dirs, np.multiply, s, by_row=True), np.add, t)    # t + dirs * s[:, None]


def matrix_to_quat(m: np.ndarray) -> tuple[float, float, float, float]:
    """Scalar-first unit quaternion of a rotation matrix."""
    m = np.asarray(m, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = math.sqrt(tr + 1.0) * 2
        q = (0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = ((m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s)
    elif m[1, 1] > m[2, 2]:
        s = math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = ((m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s)
    else:
        s = math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = ((m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s)
    n = math.sqrt(sum(c * c for c in q))
    q = tuple(c / n for c in q)
    if q[0] < 0:
        q = tuple(-c for c in q)
    return q  # type: ignore[return-value]


def camera_from_matrix(intr: dict, cam2world: np.ndarray, world_to_shelf: np.ndarray | None = None,
                       depth_scale: float = 0.001) -> Camera:
    """A `Camera` from intrinsics and a 4x4 camera-to-world pose (optionally re-based)."""
    m = np.asarray(cam2world, dtype=np.float64)
    if world_to_shelf is not None:
        m = np.asarray(world_to_shelf, dtype=np.float64) @ m
    rot = m[:3, :3]
    u, _, vt = np.linalg.svd(rot)  # re-orthonormalise a calibration matrix
    rot = u @ vt
    return Camera(int(intr["width"]), int(intr["height"]), float(intr["fx"]), float(intr["fy"]),
                  float(intr["cx"]), float(intr["cy"]), depth_scale,
                  tuple(float(c) for c in m[:3, 3]), matrix_to_quat(rot))  # type: ignore[arg-type]
