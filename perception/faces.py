"""A box front face measured in metres from one instance mask and the depth image.

A plane fitted to the depth inside the eroded mask (median-robust, holes ignored;
vertical unless the face clearly leans), the mask outline cast onto that plane, and a
minimum-area rectangle in the plane. Width, height and the in-plane angle (a turn
about the viewing axis, shelf y) come from the rectangle's long edge, never from
OpenCV's angle convention.
"""
from __future__ import annotations

import contextlib
import contextvars
import math
from collections.abc import Iterator
from dataclasses import dataclass, replace

import cv2
import numpy as np

from shelfpick.perception.geometry import backproject, offsets, ray_plane
from shelfpick.perception.pixels import count, nonzero
from shelfpick.perception.scene import Camera


@dataclass(frozen=True)
class FrontFace:
    """A measured box front face in the shelf frame."""

    center: tuple[float, float, float]
    width: float                 # along the face's in-plane x axis (m)
    height: float                # along the face's in-plane z axis (m)
    angle: float                 # in-plane turn about shelf y, degrees in (-45, 45]
    yaw: float                   # turn of the face normal about shelf z, degrees
    distance: float              # median camera depth over the eroded mask (m)
    pixels: int
    rect_px: tuple               # cv2 rotated rect in the image, for the overlay
    tilt: float = 0.0            # elevation of the face normal (box +y) above the horizontal, deg

    @property
    def size_cm(self) -> str:
        """"23x25 cm"-style size, for the adjustment notes a person reads."""
        return f"{self.width * 100:.0f}x{self.height * 100:.0f} cm"

    def to_json(self) -> dict:
        return {"center": list(self.center), "width": self.width, "height": self.height,
                "angle": self.angle, "yaw": self.yaw, "tilt": self.tilt, "distance": self.distance, "pixels": self.pixels}


def _rect_long_edge(pts: np.ndarray) -> tuple[tuple[float, float], float, float, float]:
    """Centre, width, height and angle (deg, (-45, 45]) of the min-area rectangle of 2-D points.

    The angle is that of the rectangle edge closest to the x axis; width is the
    extent along it. OpenCV's own (w, h, angle) convention is not used.
    """
    rect = cv2.minAreaRect(pts.astype(np.float32))
    corners = cv2.boxPoints(rect).astype(np.float64)
    e1 = corners[1] - corners[0]
    e2 = corners[2] - corners[1]
    l1, l2 = float(np.hypot(*e1)), float(np.hypot(*e2))
    long_e, long_l, short_l = (e1, l1, l2) if l1 >= l2 else (e2, l2, l1)
    a = math.degrees(math.atan2(long_e[1], long_e[0]))
    a = (a + 90.0) % 180.0 - 90.0          # [-90, 90)
    if -45.0 < a <= 45.0:
        width, height, angle = long_l, short_l, a
    else:
        width, height = short_l, long_l
        angle = a - 90.0 if a > 45.0 else a + 90.0
    centre = tuple(corners.mean(axis=0))
    return centre, width, height, angle  # type: ignore[return-value]


# a face whose 3-D plane tilts less than this (deg) is taken as vertical (upright boxes keep the
# vertical-plane fit they were measured with before); chosen on the tuning set 20000-20019
TILT_SNAP = 3.0


def measure_front(mask: np.ndarray, depth: np.ndarray, camera: Camera, erode_px: int = 3,
                  angle_snap: float = 1.0, tilt_snap: float = TILT_SNAP) -> FrontFace | None:
    """Measure one mask's front face; None when the mask has too little valid depth.

    Works on the mask's bounding box (the camera's principal point shifted with it):
    the same numbers as on the full frame, several times faster."""
    mask = np.asarray(mask, bool)
    rows = np.flatnonzero(mask.any(axis=1))
    if len(rows) == 0:
        return None
    cols = np.flatnonzero(mask.any(axis=0))
    pad = erode_px + 2
    y0, y1 = max(0, rows[0] - pad), min(mask.shape[0], rows[-1] + pad + 1)
    x0, x1 = max(0, cols[0] - pad), min(mask.shape[1], cols[-1] + pad + 1)
    if (y0, x0, y1, x1) != (0, 0) + mask.shape:
        sub = replace(camera, cx=camera.cx - x0, cy=camera.cy - y0)
        f = measure_front(mask[y0:y1, x0:x1], depth[y0:y1, x0:x1], sub, erode_px, angle_snap, tilt_snap)
        if f is None:
            return None
        (rx, ry), rs, ra = f.rect_px
        return replace(f, rect_px=((rx + x0, ry + y0), rs, ra))
    memo = _MEASURED.get()
    if memo is None:
        return _measure(mask, depth, camera, erode_px, angle_snap, tilt_snap)
    key = (mask.shape, mask.tobytes(), depth.dtype.str, depth.tobytes(), camera, erode_px, angle_snap, tilt_snap)
    if key not in memo:
        memo[key] = _measure(mask, depth, camera, erode_px, angle_snap, tilt_snap)
    f = memo[key]
    return None if f is None else replace(f)       # a face object of its own, as measuring gives


# the faces measured in the `perceive` call running in this context (None outside one): its
# repairs and box building measure one mask on one depth again and again (~9% of the calls)
_MEASURED: contextvars.ContextVar[dict | None] = contextvars.ContextVar("shelfpick_measured_faces", default=None)


@contextlib.contextmanager
def faces_cached() -> Iterator[dict]:
    """Within the body (one `perceive`), `measure_front` of a mask and depth (every value equal)
    already measured returns what it measured then: the same numbers, measured once."""
    memo: dict = {}
    token = _MEASURED.set(memo)
    try:
        yield memo
    finally:
        _MEASURED.reset(token)


def _measure(mask: np.ndarray, depth: np.ndarray, camera: Camera, erode_px: int, angle_snap: float,
             tilt_snap: float) -> FrontFace | None:
    """`measure_front` of a mask cropped to its bounding box (see there)."""
    m = mask.astype(np.uint8)
    if count(m) < 20:                    # m: the bool mask as 0/1
        return None
    got = _face_points(m, depth, camera, erode_px)
    if got is None:
        return None
    pts, dmed = got
    centre, normal, pts = _vertical_plane(pts)
    yaw = math.degrees(math.atan2(-normal[0], normal[1]))
    tilt, yaw3 = _tilt(pts, centre)
    if abs(tilt) >= tilt_snap:
        yaw = yaw3                       # a leaning face: the 3-D plane's own yaw
    else:
        tilt = 0.0                       # an upright face: the vertical plane, as before
    if abs(yaw) < 2.0:
        yaw = 0.0
    normal = face_normal(yaw, tilt)
    # outline of the full mask cast onto the plane
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    if not contours:
        return None
    outline = np.concatenate([c.reshape(-1, 2) for c in contours], axis=0).astype(np.float64)
    got_axes = _in_plane_axes(outline, camera, centre, normal, angle_snap)
    if got_axes is None:
        return None
    angle, ex, ez = got_axes
    c3, width, height = _extents(m, camera, centre, normal, ex, ez)
    rect_px = cv2.minAreaRect(outline.astype(np.float32))
    return FrontFace(tuple(float(x) for x in c3), float(width), float(height), float(angle),  # type: ignore[arg-type]
                     float(yaw), dmed, count(m), rect_px, float(tilt))


def _face_points(m: np.ndarray, depth: np.ndarray, camera: Camera,
                 erode_px: int) -> tuple[np.ndarray, float] | None:
    """Shelf-frame points of the eroded mask's valid depth within a few cm of its median (at
    most ~6000), and that median depth; None with fewer than 10 valid pixels."""
    k = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
    inner = cv2.erode(m, k) > 0
    if count(inner) < 20:
        inner = m > 0
    d = depth
    sel = inner & np.isfinite(d) & (d > 0)
    if count(sel) < 10:
        return None
    vs, us = nonzero(sel)
    z = d[vs, us].astype(np.float64)
    dmed = float(np.median(z))
    keep = np.abs(z - dmed) < max(0.04, 0.05 * dmed)
    vs, us, z = vs[keep], us[keep], z[keep]
    if len(z) > 6000:
        step = len(z) // 6000 + 1
        vs, us, z = vs[::step], us[::step], z[::step]
    return backproject(camera, us, vs, z), dmed


def _vertical_plane(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centre, normal, inlier points) of a vertical plane (normal in the shelf x-y plane)
    fitted robustly to the points: two rounds of a PCA in x-y, outliers dropped."""
    centre = np.median(pts, axis=0)
    normal = np.array([0.0, 1.0, 0.0])
    for _ in range(2):
        q = offsets(pts, centre)
        cov = q[:, :2].T @ q[:, :2]
        w, v = np.linalg.eigh(cov)
        n2 = v[:, 0]                          # smallest spread in x-y = normal direction
        if n2[1] < 0:
            n2 = -n2
        normal = np.array([n2[0], n2[1], 0.0])
        res = np.abs(q @ normal)
        cut = max(0.006, 3.0 * float(np.median(res)))
        inl = res < cut
        if 10 <= count(inl) < len(pts):             # (all inliers, 4 rounds in 5: the same points and centre)
            pts = np.compress(inl, pts, axis=0)     # pts[inl], 4x faster for rows
            centre = np.median(pts, axis=0)
    return centre, normal, pts


def _in_plane_axes(outline: np.ndarray, camera: Camera, centre: np.ndarray, normal: np.ndarray,
                   angle_snap: float) -> tuple[float, np.ndarray, np.ndarray] | None:
    """(angle, ex, ez): the in-plane turn (deg) of the outline cast onto the face plane, and
    the face's x and z axes turned by it; None when fewer than 4 outline rays hit the plane."""
    hit = ray_plane(camera, outline[:, 0], outline[:, 1], centre, normal)
    hit = hit[np.all(np.isfinite(hit), axis=1)]
    if len(hit) < 4:
        return None
    u_ax = _cross(normal, (0.0, 0.0, 1.0))
    u_ax /= np.linalg.norm(u_ax)
    v_ax = _cross(u_ax, normal)
    rel = offsets(hit, centre)
    ab = np.stack([rel @ u_ax, rel @ v_ax], axis=1)
    _, _, _, angle = _rect_long_edge(ab * 1000.0)   # orientation from the outline (mm precision)
    if abs(angle) < angle_snap:
        angle = 0.0
    a = math.radians(angle)
    ex = math.cos(a) * u_ax + math.sin(a) * v_ax
    ez = -math.sin(a) * u_ax + math.cos(a) * v_ax
    return angle, ex, ez


def _extents(m: np.ndarray, camera: Camera, centre: np.ndarray, normal: np.ndarray,
             ex: np.ndarray, ez: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(centre, width, height) of the face along ex, ez: weighted quantiles of every mask pixel
    cast onto the plane, so a few stray pixels cannot inflate the rectangle, and pixel
    footprints (~z^3) weight the far side fairly."""
    ys_all, xs_all = nonzero(m)
    if len(xs_all) > 20000:
        st = len(xs_all) // 20000 + 1
        ys_all, xs_all = ys_all[::st], xs_all[::st]
    allp = ray_plane(camera, xs_all.astype(np.float64), ys_all.astype(np.float64), centre, normal)
    fin = np.isfinite(allp)
    okp = fin[:, 0] & fin[:, 1] & fin[:, 2]      # np.all(fin, axis=1), without its reduction set-up
    if not okp.all():
        allp = np.compress(okp, allp, axis=0)
    rel = offsets(allp, centre)
    cam_t = np.asarray(camera.position, dtype=np.float64)
    wts = np.linalg.norm(offsets(allp, cam_t), axis=1) ** 3
    q = 0.02
    (x_lo, x_hi), (z_lo, z_hi) = (_wquant(rel @ ax, wts, (q, 1 - q)) for ax in (ex, ez))
    width = (x_hi - x_lo) / (1 - 2 * q)
    height = (z_hi - z_lo) / (1 - 2 * q)
    c3 = centre + ex * (x_lo + x_hi) / 2 + ez * (z_lo + z_hi) / 2
    return c3, width, height


def _tilt(pts: np.ndarray, centre: np.ndarray, rounds: int = 3) -> tuple[float, float]:
    """(tilt, yaw) in degrees of the plane through the face's points, fitted in 3-D by least
    squares with outlier rejection (points beyond 3x the median residual, at least 4 mm, are
    dropped and the plane refitted). Why: a box leaning back or forward shows a face whose
    normal leaves the horizontal; the vertical-plane fit would put its top and bottom edges at
    the wrong depth. tilt > 0: the inward normal (box +y) points up, the face leans forward."""
    p = pts
    c = centre
    n = np.array([0.0, 1.0, 0.0])
    for _ in range(rounds):
        if len(p) < 10:
            break
        c = p.mean(axis=0)
        q = offsets(p, c)
        n = np.linalg.svd(q, full_matrices=False)[2][2]
        if n[1] < 0:
            n = -n
        res = np.abs(q @ n)
        keep = res < max(0.004, 3.0 * float(np.median(res)))
        if keep.all():
            break
        p = np.compress(keep, p, axis=0)
    tilt = math.degrees(math.asin(max(-1.0, min(1.0, float(n[2])))))
    return tilt, math.degrees(math.atan2(-n[0], n[1]))


def face_normal(yaw: float, tilt: float = 0.0) -> np.ndarray:
    """The inward unit normal (box +y) of a face turned `yaw` deg about shelf z whose normal
    rises `tilt` deg above the horizontal."""
    y, t = math.radians(yaw), math.radians(tilt)
    return np.array([-math.sin(y) * math.cos(t), math.cos(y) * math.cos(t), math.sin(t)])


def _wquant(x: np.ndarray, w: np.ndarray, qs: tuple[float, float]) -> tuple[float, float]:
    order = np.argsort(x)
    cw = np.cumsum(w[order])
    cw /= cw[-1]
    xs = x[order]
    return tuple(float(xs[min(np.searchsorted(cw, q), len(x) - 1)]) for q in qs)  # type: ignore[return-value]


def _cross(a, b) -> np.ndarray:
    """`np.cross` of two float64 3-vectors, its formula term by term in Python floats: the same
    IEEE products and differences, without np.cross's broadcasting set-up (~30 us a call; a
    frame asks for thousands of face axes)."""
    a0, a1, a2 = (float(x) for x in a)
    b0, b1, b2 = (float(x) for x in b)
    return np.array([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0])


def face_axes(face: FrontFace) -> np.ndarray:
    """Box rotation matrix (columns: box x, y, z in the shelf frame) of a measured face: its
    normal from yaw and tilt, its x axis the plane's horizontal turned by the in-plane angle."""
    n = face_normal(face.yaw, face.tilt)
    u = _cross(n, (0.0, 0.0, 1.0))
    u /= np.linalg.norm(u)
    v = _cross(u, n)
    a = math.radians(face.angle)
    ex = math.cos(a) * u + math.sin(a) * v
    ez = -math.sin(a) * u + math.cos(a) * v
    return np.stack([ex, n, ez], axis=1)
