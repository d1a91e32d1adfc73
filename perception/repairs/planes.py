"""Pixels measured on a face's plane: where they lie on it, how far off it they are, and two
pieces joined with the unclaimed on-plane pixels between them."""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.faces import FrontFace, face_axes
from shelfpick.perception.geometry import backproject, ray_plane
# plane_dist lives with RepairContext (neighbour_pieces measures with it); named here too, beside
# the other on-plane measures, for the steps that import it from here
from shelfpick.perception.pixels import count, hull_candidates, nonzero
from shelfpick.perception.repairs.crop import Window, box_nonzero
from shelfpick.perception.repairs.measure import RepairContext, plane_dist
from shelfpick.perception.scene import Camera


def coords(face: FrontFace, mask: np.ndarray,
           camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of the mask and their (x, z) on the measured face plane, centred on the face."""
    rot = face_axes(face)
    c = np.asarray(face.center, float)
    ys, xs = box_nonzero(mask)
    hit = ray_plane(camera, xs.astype(np.float64), ys.astype(np.float64), c, rot[:, 1])
    rel = hit - c
    return ys, xs, rel @ rot[:, 0], rel @ rot[:, 2]


def extent(v: np.ndarray, q: float = 0.02) -> float:
    """The length of a side from its pixels' coordinates, robust to `q` stray pixels each end."""
    if len(v) < 10:
        return 0.0
    lo, hi = np.quantile(v, (q, 1 - q))
    return float(hi - lo) / (1 - 2 * q)


def plane_res(face: FrontFace, where: np.ndarray, ctx: RepairContext, win: Window | None = None) -> np.ndarray:
    """Per pixel of `where`, the distance (m) of its depth point to the plane of `face`
    (inf where there is no depth or outside `where`); of the frame's window `win` only (one
    holding `where`: the rest is all inf), None: of the whole frame."""
    depth = ctx.depth
    out = np.full(where.shape if win is None else where[win].shape, np.inf)
    ys, xs = box_nonzero(where, ctx.valid)
    if len(xs):
        p = backproject(ctx.camera, xs.astype(np.float64), ys.astype(np.float64),
                        depth[ys, xs].astype(np.float64))
        at = (ys, xs) if win is None else (ys - win[0].start, xs - win[1].start)
        out[at] = np.abs((p - np.asarray(face.center)) @ face_axes(face)[:, 1])
    return out


def on_plane(face: FrontFace, where: np.ndarray, ctx: RepairContext, tol: float) -> np.ndarray:
    """The pixels of `where` whose depth point lies within `tol` of the plane of `face`."""
    depth = ctx.depth
    out = np.zeros_like(where)
    ys, xs = box_nonzero(where, ctx.valid)
    if len(xs):
        p = backproject(ctx.camera, xs.astype(np.float64), ys.astype(np.float64),
                        depth[ys, xs].astype(np.float64))
        near = np.abs((p - np.asarray(face.center)) @ face_axes(face)[:, 1]) <= tol
        out[ys[near], xs[near]] = True
    return out


def rect_fill(m: np.ndarray) -> float:
    """Area over the area of the axis-aligned bounding rectangle (image rows/columns)."""
    rows = np.flatnonzero(m.any(axis=1))
    cols = np.flatnonzero(m.any(axis=0))
    if len(rows) == 0:
        return 0.0
    return float(count(m)) / float((rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1))


def largest_component(m: np.ndarray) -> tuple[np.ndarray, bool]:
    """(the mask's largest 4-connected part, whether it has more than one) ((m, False) if not)."""
    n, lbl, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=4)
    if n <= 2:
        return m, False
    return lbl == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])), True


def min_area_rect(m: np.ndarray) -> np.ndarray:
    """The filled min-area rectangle around the mask's pixels (uint8, 1 inside)."""
    rect = np.zeros(m.shape, np.uint8)
    pts = hull_candidates(m)
    cv2.fillPoly(rect, [np.round(cv2.boxPoints(cv2.minAreaRect(pts))).astype(np.int32)], 1)
    return rect


def join_on_plane(a: np.ndarray, b: np.ndarray, face: FrontFace, taken: np.ndarray,
                  ctx: RepairContext) -> tuple[np.ndarray, float]:
    """Two pieces joined with the unclaimed pixels between them that lie on their plane (a
    label, a tape edge, the depth holes of a seam), within the union's min-area rectangle;
    and how well that fills the rectangle."""
    u = a | b
    rows = np.flatnonzero(u.any(axis=1))
    cols = np.flatnonzero(u.any(axis=0))
    y0, y1 = max(0, rows[0] - 2), min(u.shape[0], rows[-1] + 3)
    x0, x1 = max(0, cols[0] - 2), min(u.shape[1], cols[-1] + 3)
    uc = u[y0:y1, x0:x1]
    sub = cv2.morphologyEx(uc.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    if cv2.findNonZero(sub) is None:
        return u, 0.0
    rect = min_area_rect(sub) > 0
    cand = uc & rect
    _add_on_plane(cand, rect & ~uc & ~taken[y0:y1, x0:x1], face, ctx, y0, x0)
    fill = float(count(cand)) / max(float(count(rect)), 1.0)
    cand, _ = largest_component(cand)
    ac, bc = a[y0:y1, x0:x1], b[y0:y1, x0:x1]
    if count(cand & ac) < 0.9 * count(ac) or count(cand & bc) < 0.9 * count(bc):
        return u, 0.0          # the pieces do not connect on their plane
    if through_gap(u, face, ctx, (slice(y0, y1), slice(x0, x1))):
        return u, 0.0          # they connect only across a gap: two things, not one face
    out = np.zeros_like(u)
    out[y0:y1, x0:x1] = cand | (uc & ~rect)
    return out, fill


def through_gap(u: np.ndarray, face: FrontFace, ctx: RepairContext, win: Window,
                bin_m: float = 0.01) -> bool:
    """Whether a band across `u` (1 cm wide, along either axis of the face) with most of its
    pixels with depth lying more than `gap_off` off the face's plane has bands of the face on both
    sides (a band at one end is the box's top or side, seen with it). A carton's face
    is flat, and tape or a label lies on it; a band of the union that the depth sees far behind
    it is the gap between two boxes (a mask that had covered both, cut and offered to be joined
    again), seen through to the shelf behind. `win`: a window of the frame holding `u`."""
    res = plane_res(face, u, ctx, win)
    ys, xs, px, pz = coords(face, u, ctx.camera)
    r = res[ys - win[0].start, xs - win[1].start]
    has = np.isfinite(r)
    if count(has) < 50:
        return False
    far = has & (r > ctx.cat.gap_off)
    for v in (px, pz):
        b = np.floor((v - v.min()) / bin_m).astype(np.int64)
        nb = int(b.max()) + 1
        if nb < 3:
            continue
        tot = np.bincount(b[has], minlength=nb)
        off = np.bincount(b[far], minlength=nb)
        gap = (tot >= 10) & (off > ctx.cat.gap_share * tot)
        on_face = (tot >= 10) & ~gap
        on_before = np.cumsum(on_face) > 0                   # some face band at or before it
        on_after = np.cumsum(on_face[::-1])[::-1] > 0        # ... and at or after it
        if np.any(gap & on_before & on_after):
            return True
    return False


def _add_on_plane(cand: np.ndarray, free: np.ndarray, face: FrontFace, ctx: RepairContext,
                  y0: int, x0: int) -> None:
    """Set the pixels of `free` (a crop at y0, x0) whose depth point lies on the face's plane."""
    d = ctx.depth[y0:y0 + free.shape[0], x0:x0 + free.shape[1]]
    free = free & np.isfinite(d) & (d > 0)
    ys, xs = nonzero(free)
    if len(xs):
        p = backproject(ctx.camera, (xs + x0).astype(np.float64), (ys + y0).astype(np.float64),
                        d[ys, xs].astype(np.float64))
        on = np.abs((p - np.asarray(face.center)) @ face_axes(face)[:, 1]) < ctx.cat.plane_tol
        cand[ys[on], xs[on]] = True


def band_trim(pieces: np.ndarray, other: np.ndarray, face: FrontFace, camera: Camera,
              margin: float = 0.01) -> np.ndarray | None:
    """`other` cut to the band that `pieces` span along one axis of `face` (the axis that trims
    less of it: at least 2%, at most a third, a strip sticking out), or None when neither does."""
    _, _, px, pz = coords(face, pieces, camera)
    ys, xs, ox, oz = coords(face, other, camera)
    if len(px) < 10 or len(ox) < 10:
        return None
    best = None
    for p, o in ((pz, oz), (px, ox)):
        lo, hi = np.quantile(p, (0.01, 0.99))
        keep = (o >= lo - margin) & (o <= hi + margin)
        if 0.02 * len(o) <= count(~keep) <= len(o) / 3 and (best is None or count(keep) > count(best)):
            best = keep
    if best is None:
        return None
    out = np.zeros_like(other)
    out[ys[best], xs[best]] = True
    return out
