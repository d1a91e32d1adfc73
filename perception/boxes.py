"""From instance masks to boxes in the shelf frame, and a scene that can stand.

Per mask the front face is measured in metres: a plane fitted to the depth
inside the eroded mask (median-robust, holes ignored), the mask outline cast
onto that plane, and a minimum-area rectangle in the plane. Width, height and
the in-plane angle (a turn about the viewing axis, shelf y) come from the
rectangle's long edge, never from OpenCV's angle convention. The camera sees
no depth, so boxes get `depth_known: false` and a placeholder depth behind the
measured front. `make_valid` then rests every box on the floor or on a box
below (closing small gaps, resolving small overlaps), keeps boxes inside the
shelf, and says what it moved.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import cv2
import numpy as np

from perception.errors import PerceptionError
from perception.geometry import backproject, matrix_to_quat, ray_plane
from perception.masks import border_sides
from perception.scene import Box, Camera, Shelf, quat_to_matrix


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
    m = mask.astype(np.uint8)
    if m.sum() < 20:
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
                     float(yaw), dmed, int(m.sum()), rect_px, float(tilt))


def _face_points(m: np.ndarray, depth: np.ndarray, camera: Camera,
                 erode_px: int) -> tuple[np.ndarray, float] | None:
    """Shelf-frame points of the eroded mask's valid depth within a few cm of its median (at
    most ~6000), and that median depth; None with fewer than 10 valid pixels."""
    k = np.ones((2 * erode_px + 1, 2 * erode_px + 1), np.uint8)
    inner = cv2.erode(m, k) > 0
    if inner.sum() < 20:
        inner = m > 0
    d = depth
    sel = inner & np.isfinite(d) & (d > 0)
    if sel.sum() < 10:
        return None
    vs, us = np.nonzero(sel)
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
        q = pts - centre
        cov = q[:, :2].T @ q[:, :2]
        w, v = np.linalg.eigh(cov)
        n2 = v[:, 0]                          # smallest spread in x-y = normal direction
        if n2[1] < 0:
            n2 = -n2
        normal = np.array([n2[0], n2[1], 0.0])
        res = np.abs(q @ normal)
        cut = max(0.006, 3.0 * float(np.median(res)))
        inl = res < cut
        if inl.sum() >= 10:
            centre = np.median(pts[inl], axis=0)
            pts = pts[inl]
    return centre, normal, pts


def _in_plane_axes(outline: np.ndarray, camera: Camera, centre: np.ndarray, normal: np.ndarray,
                   angle_snap: float) -> tuple[float, np.ndarray, np.ndarray] | None:
    """(angle, ex, ez): the in-plane turn (deg) of the outline cast onto the face plane, and
    the face's x and z axes turned by it; None when fewer than 4 outline rays hit the plane."""
    hit = ray_plane(camera, outline[:, 0], outline[:, 1], centre, normal)
    hit = hit[np.all(np.isfinite(hit), axis=1)]
    if len(hit) < 4:
        return None
    u_ax = np.cross(normal, [0.0, 0.0, 1.0])
    u_ax /= np.linalg.norm(u_ax)
    v_ax = np.cross(u_ax, normal)
    ab = np.stack([(hit - centre) @ u_ax, (hit - centre) @ v_ax], axis=1)
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
    ys_all, xs_all = np.nonzero(m)
    if len(xs_all) > 20000:
        st = len(xs_all) // 20000 + 1
        ys_all, xs_all = ys_all[::st], xs_all[::st]
    allp = ray_plane(camera, xs_all.astype(np.float64), ys_all.astype(np.float64), centre, normal)
    okp = np.all(np.isfinite(allp), axis=1)
    allp = allp[okp]
    rel = allp - centre
    cam_t = np.asarray(camera.position, dtype=np.float64)
    wts = np.linalg.norm(allp - cam_t, axis=1) ** 3
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
        n = np.linalg.svd(p - c, full_matrices=False)[2][2]
        if n[1] < 0:
            n = -n
        res = np.abs((p - c) @ n)
        keep = res < max(0.004, 3.0 * float(np.median(res)))
        if keep.all():
            break
        p = p[keep]
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
    return tuple(float(x[order][min(np.searchsorted(cw, q), len(x) - 1)]) for q in qs)  # type: ignore[return-value]


def face_axes(face: FrontFace) -> np.ndarray:
    """Box rotation matrix (columns: box x, y, z in the shelf frame) of a measured face: its
    normal from yaw and tilt, its x axis the plane's horizontal turned by the in-plane angle."""
    n = face_normal(face.yaw, face.tilt)
    u = np.cross(n, [0.0, 0.0, 1.0])
    u /= np.linalg.norm(u)
    v = np.cross(u, n)
    a = math.radians(face.angle)
    ex = math.cos(a) * u + math.sin(a) * v
    ez = -math.sin(a) * u + math.cos(a) * v
    return np.stack([ex, n, ez], axis=1)


def box_from_face(face: FrontFace, box_id: str, label: int, shelf: Shelf,
                  placeholder: float = 0.25) -> Box:
    """A box whose front face is the measured one and whose depth is a placeholder."""
    rot = face_axes(face)
    front_y = face.center[1]
    depth = min(placeholder, shelf.depth - front_y)
    depth = max(depth, 0.02)
    pos = np.asarray(face.center) + rot[:, 1] * depth / 2
    return Box(box_id, (face.width, depth, face.height), tuple(float(x) for x in pos),  # type: ignore[arg-type]
               matrix_to_quat(rot), None, False, label,
               {"perceived": {"angle_deg": round(face.angle, 3), "yaw_deg": round(face.yaw, 3),
                              "tilt_deg": round(face.tilt, 3), "distance": round(face.distance, 4)}})


# --------------------------------------------------------------------------
# physically valid scene
def _aabb(b: Box) -> np.ndarray:
    c = np.asarray(b.corners())
    return np.stack([c.min(axis=0), c.max(axis=0)])


def _moved(b: Box, delta: np.ndarray) -> Box:
    return replace(b, position=tuple(float(p + d) for p, d in zip(b.position, delta)))  # type: ignore[arg-type]


def _overlap(a: np.ndarray, b: np.ndarray, axis: int) -> float:
    return float(min(a[1, axis], b[1, axis]) - max(a[0, axis], b[0, axis]))


def make_valid(boxes: list[Box], shelf: Shelf, snap: float = 0.03,
               min_contact: float = 0.01) -> tuple[list[Box], list[str]]:
    """Boxes resting on the floor or on each other, inside the shelf; and what was changed.

    Geometric, no physics: small gaps (<= `snap`) under a box are closed, small
    overlaps pushed apart (up, or sideways for neighbours), a box with nothing
    under it is dropped onto the nearest support below, and boxes are clamped
    into the shelf. Placeholder depths shrink to fit before the back wall.
    """
    notes: list[str] = []
    out = [_clamp(b, shelf, notes) for b in boxes]
    out, said = _push_apart(out, snap, min_contact)
    notes += said
    out = [_clamp(b, shelf, notes) for b in out]
    out, said = _rest_on_supports(out, snap, min_contact)
    notes += said
    for b in out:
        top = _aabb(b)[1, 2]
        if top > shelf.height + 1e-6:
            notes.append(f"{b.id}: reaches {top:.3f} m, above the shelf height {shelf.height:.3f} m")
    return out, notes


def _push_apart(boxes: list[Box], snap: float, min_contact: float) -> tuple[list[Box], list[str]]:
    """Neighbours side by side at one height that overlap sideways by at most `snap`, moved
    apart by half the overlap each; and what was moved."""
    out = list(boxes)
    notes: list[str] = []
    order = sorted(range(len(out)), key=lambda i: _aabb(out[i])[0, 0])
    for ii, i in enumerate(order):
        for j in order[ii + 1:]:
            a, c = _aabb(out[i]), _aabb(out[j])
            ox = _overlap(a, c, 0)
            if ox <= 0 or _overlap(a, c, 2) < min_contact or _overlap(a, c, 1) <= 0:
                continue
            # only neighbours side by side (their centres apart more in x than z)
            dxc = abs((a[0, 0] + a[1, 0]) - (c[0, 0] + c[1, 0])) / 2
            dzc = abs((a[0, 2] + a[1, 2]) - (c[0, 2] + c[1, 2])) / 2
            if ox > snap or dzc > dxc:
                continue
            left, right = (i, j) if a[0, 0] <= c[0, 0] else (j, i)
            half = ox / 2 + 1e-4
            out[left] = _moved(out[left], np.array([-half, 0, 0]))
            out[right] = _moved(out[right], np.array([half, 0, 0]))
            notes.append(f"{out[left].id}/{out[right].id}: pushed apart sideways by {ox * 100:.1f} cm overlap")
    return out, notes


def _rest_on_supports(boxes: list[Box], snap: float, min_contact: float) -> tuple[list[Box], list[str]]:
    """Every box, lowest first, moved up or down onto the floor or the highest box under it;
    and what was moved (more than 1 mm)."""
    out = list(boxes)
    notes: list[str] = []
    order = sorted(range(len(out)), key=lambda i: _aabb(out[i])[0, 2])
    placed: list[int] = []
    for i in order:
        a = _aabb(out[i])
        bottom = a[0, 2]
        support, under = 0.0, "the floor"
        for j in placed:
            c = _aabb(out[j])
            if _overlap(a, c, 0) < min_contact or _overlap(a, c, 1) <= 0:
                continue
            # under this box: its top within `snap` above our bottom, or (a larger overlap)
            # its bottom below ours: we were measured partly inside it, so we rest on it
            if (c[1, 2] <= bottom + snap or c[0, 2] < bottom - 1e-3) and c[1, 2] > support:
                support, under = float(c[1, 2]), out[j].id
        delta = support - bottom
        if abs(delta) > 1e-3:
            if delta > 0:
                notes.append(f"{out[i].id}: pushed up {delta * 100:.1f} cm out of {under}")
            elif -delta <= snap:
                notes.append(f"{out[i].id}: lowered {-delta * 100:.1f} cm onto {under} (gap closed)")
            else:
                notes.append(f"{out[i].id}: hung {-delta * 100:.1f} cm in the air; dropped onto {under}")
            out[i] = _moved(out[i], np.array([0.0, 0.0, delta]))
        elif delta != 0:
            out[i] = _moved(out[i], np.array([0.0, 0.0, delta]))
        placed.append(i)
    return out, notes


def _clamp(b: Box, shelf: Shelf, notes: list[str]) -> Box:
    a = _aabb(b)
    half = shelf.width / 2
    dx = 0.0
    if a[1, 0] - a[0, 0] > shelf.width:
        dx = -(a[0, 0] + a[1, 0]) / 2
    elif a[0, 0] < -half:
        dx = -half - a[0, 0]
    elif a[1, 0] > half:
        dx = half - a[1, 0]
    if abs(dx) > 1e-6:
        b = _moved(b, np.array([dx, 0.0, 0.0]))
        if abs(dx) > 1e-3:
            notes.append(f"{b.id}: moved {abs(dx) * 100:.1f} cm {'right' if dx > 0 else 'left'} into the shelf")
    a = _aabb(b)
    if a[1, 1] > shelf.depth + 1e-6:
        excess = a[1, 1] - shelf.depth
        if not b.depth_known and b.size[1] - excess >= 0.01:
            b = b.with_depth(b.size[1] - excess)
        else:
            b = _moved(b, np.array([0.0, -excess, 0.0]))
            if excess > 1e-3:
                notes.append(f"{b.id}: moved {excess * 100:.1f} cm forward off the back wall")
    a = _aabb(b)
    if a[0, 2] < 0:
        b = _moved(b, np.array([0.0, 0.0, -a[0, 2]]))
    return b


# a face may stick out of the shelf by this much (boxes overhang the front, masks bleed a little)
FRONT_MARGIN = 0.10
# and stand this far in front of the shelf's front plane before it cannot be on the shelf
MAX_PROTRUSION = 0.50


def not_a_front(f: FrontFace, shelf: Shelf) -> str:
    """Why a measured face cannot be a box on this shelf ('' when it can).

    A mask of the floor, a wall, a neighbouring bay or (in a photo with a flat stand-in depth) a
    region near the horizon back-projects to faces metres wide or far away; kept, `make_valid`
    would stack every other box on top of them.
    """
    x, y, z = (float(v) for v in f.center)
    m = FRONT_MARGIN
    if not all(math.isfinite(v) for v in (x, y, z, f.width, f.height)):
        return "not finite"
    if f.width < 0.02 or f.height < 0.02:
        return "smaller than 2 cm"
    if f.width > shelf.width + m or f.height > shelf.height + m:
        return f"larger than the {shelf.width:.2f}x{shelf.height:.2f} m shelf"
    if y > shelf.depth + 0.05:
        return "behind the shelf's back wall"
    if y < -MAX_PROTRUSION:
        return f"more than {MAX_PROTRUSION:.2f} m in front of the shelf"
    if abs(x) - f.width / 2 > shelf.width / 2 + m or z - f.height / 2 > shelf.height + m \
            or z + f.height / 2 < -m:
        return "outside the shelf"
    return ""


# a box front face, even partly hidden, fills its min-area rectangle this well (rendered tuning
# sets 700-719, 800-839: every matched mask >= 0.68) ...
MIN_RECT_FILL = 0.5
# ... and is no strip thinner than this and this many times as long, unless an image border
# (top, left, right) cuts it (matched masks there: short side >= 15 cm, long / short <= 3.4)
STRIP_MAX_SIDE = 0.10
STRIP_MIN_ASPECT = 5.0


def not_a_face(f: FrontFace, mask: np.ndarray) -> str:
    """Why a mask on the shelf is still no box front ('' when it can be): a ragged region filling
    its rectangle less than `MIN_RECT_FILL` (the dark edge of a machine base), or a long thin
    strip not cut by the top/left/right border (pallet boards seen from above, shelf lips)."""
    ys, xs = np.nonzero(mask)
    if len(xs) < 3:
        return ""
    (_, _), (rw, rh), _ = cv2.minAreaRect(np.column_stack([xs, ys]).astype(np.float32))
    fill = len(xs) / max(rw * rh, 1.0)
    if fill < MIN_RECT_FILL:
        return f"fills only {fill:.2f} of its rectangle"
    short, long_ = sorted((f.width, f.height))
    if short < STRIP_MAX_SIDE and long_ >= STRIP_MIN_ASPECT * short and \
            not border_sides(mask, sides=("top", "left", "right")):
        return f"a {long_ * 100:.0f}x{short * 100:.0f} cm strip"
    return ""


# --------------------------------------------------------------------------
def boxes_from_masks(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, shelf: Shelf,
                     placeholder: float = 0.25, faces: list[FrontFace | None] | None = None,
                     ) -> tuple[list[Box], list[np.ndarray], list[FrontFace], list[str]]:
    """Measure every mask; boxes get ids b0.. ordered bottom-up then left to right.

    Returns boxes, the masks in the same order (mask_label = index + 1), the faces
    and warnings about masks that could not be measured. `faces`: the masks' faces when
    they were measured already (`measure_front` on the same depth), None to measure here.
    """
    warnings: list[str] = []
    measured = faces
    faces: list[tuple[FrontFace, np.ndarray]] = []  # type: ignore[no-redef]
    for i, m in enumerate(masks):
        f = measured[i] if measured is not None else measure_front(m, depth, camera)
        if f is None:
            warnings.append(f"mask {i + 1}: too little valid depth to measure; dropped")
            continue
        why = not_a_front(f, shelf) or not_a_face(f, m)
        if not why and f.center[1] + placeholder < 0.01:
            # its box (placeholder depth) would lie wholly in front of the shelf: a scene the
            # format refuses to load (a flat depth 0.5 m from the camera wrote one)
            why = f"its box, {placeholder:.2f} m deep, would not reach into the shelf"
        if why:
            warnings.append(f"mask {i + 1}: face at x={f.center[0]:.2f} y={f.center[1]:.2f} z={f.center[2]:.2f} m, "
                            f"{f.width:.3f}x{f.height:.3f} m is not a box front ({why}); dropped")
            continue
        faces.append((f, m))
    faces.sort(key=lambda fm: (round((fm[0].center[2] - fm[0].height / 2) / 0.05), fm[0].center[0]))
    boxes = [box_from_face(f, f"b{k}", k + 1, shelf, placeholder) for k, (f, _) in enumerate(faces)]
    return boxes, [m for _, m in faces], [f for f, _ in faces], warnings


def planar_depth(camera: Camera, distance: float) -> np.ndarray:
    """A depth image of a flat front at `distance` m in front of the camera (no depth sensor)."""
    if not (distance > 0 and math.isfinite(distance)):
        raise PerceptionError(f"front distance must be a positive number of metres, got {distance!r}")
    return np.full((camera.height, camera.width), float(distance), np.float32)


def distance_from_box_size(masks: list[np.ndarray], camera: Camera, box_size: tuple[float, float]) -> float:
    """The distance at which the median mask's pixel size matches a known front-face size (W, H in m)."""
    if len(box_size) != 2 or min(box_size) <= 0:
        raise PerceptionError(f"--box-size needs two positive sizes in metres (W H), got {box_size!r}")
    long_m, short_m = max(box_size), min(box_size)
    f = math.sqrt(camera.fx * camera.fy)
    est = []
    for m in masks:
        pts = cv2.findNonZero(m.astype(np.uint8))
        if pts is None or len(pts) < 20:
            continue
        (_, _), (w, h), _ = cv2.minAreaRect(pts)
        lp, sp = max(w, h) + 1, min(w, h) + 1
        est.append(0.5 * (f * long_m / lp + f * short_m / sp))
    if not est:
        raise PerceptionError("cannot derive a distance from --box-size: no box was found in the image")
    return float(np.median(est))


def default_front_distance(camera: Camera) -> float:
    """Distance along the optical axis from the camera to the shelf's front plane (y = 0)."""
    rot = np.asarray(quat_to_matrix(camera.orientation))
    fwd = rot[:, 2]
    if fwd[1] <= 1e-3 or camera.position[1] >= 0:
        return 1.0
    return float(-camera.position[1] / fwd[1])   # camera z of the plane along the optical axis
