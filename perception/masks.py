"""Instance masks: cleaning, splitting at depth jumps, de-duplication, label images.

Whatever segmenter produced them, masks are made usable the same way: small
blobs dropped, holes (labels, tape, depth holes) filled, a mask that covers
two boxes at different distances split in two, and overlaps resolved so each
pixel belongs to at most one box.
"""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.crop import box, box_nonzero

REF_DEPTH = 1.2      # m: the face distance the pixel thresholds were tuned at (default camera)


def pixel_scale(depth: np.ndarray | None, where: np.ndarray | None = None, ref: float = REF_DEPTH,
                least: float = 0.3) -> float:
    """How many pixels a metre spans here relative to the tuning distance: ref / median depth
    of the valid pixels in `where` (f / depth, the focal length cancels), at most 1 (closer than
    `ref`: thresholds stay as tuned) and at least `least`. Why: pixel thresholds tuned at ~1 m
    must shrink with the faces when the camera stands further back."""
    if depth is None:
        return 1.0
    d = np.asarray(depth, np.float32)
    sel = np.isfinite(d) & (d > 0)
    if where is not None and (sel & where).any():
        sel &= where
    if not sel.any():
        return 1.0
    return float(np.clip(ref / float(np.median(d[sel])), least, 1.0))


def scaled_px(px: float, scale: float, least: int = 1) -> int:
    """A pixel threshold at `scale` (rounded, never below `least`)."""
    return max(least, int(round(px * scale)))


def fill_holes(mask: np.ndarray) -> np.ndarray:
    """The mask with every hole that does not touch the image border filled.

    Flooded within the mask's bounding box grown by a pixel (all the image outside it reaches the
    border, and so does that ring): the same holes as flooding the frame, ~10x faster a mask."""
    out = mask.astype(bool)
    win = box(out, 1)
    if win is None:
        return out
    m = mask[win].astype(np.uint8)
    h, w = m.shape
    flood = np.zeros((h + 2, w + 2), np.uint8)
    flood[1:-1, 1:-1] = m
    ff = np.zeros((h + 4, w + 4), np.uint8)
    cv2.floodFill(flood, ff, (0, 0), 1)
    out[win] |= flood[1:-1, 1:-1] == 0
    return out


def drop_small(mask: np.ndarray, min_pixels: int) -> np.ndarray:
    """Keep the connected pieces of at least `min_pixels` (8-connected)."""
    n, lbl, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    keep = np.zeros(n, bool)
    keep[1:] = stats[1:, cv2.CC_STAT_AREA] >= min_pixels
    return keep.take(lbl)


def largest_component(mask: np.ndarray) -> np.ndarray:
    n, lbl, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=8)
    if n <= 1:
        return np.zeros(mask.shape, bool)
    return lbl == (1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA])))


def clean_mask(mask: np.ndarray, min_pixels: int = 200, open_px: int = 1) -> np.ndarray:
    """Small blobs dropped, holes filled, ragged one-pixel spurs opened away."""
    m = mask.astype(bool)
    if open_px > 0 and m.any():
        k = np.ones((2 * open_px + 1, 2 * open_px + 1), np.uint8)
        m = cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN, k) > 0
    m = drop_small(m, min_pixels)
    return fill_holes(m) if m.any() else m


def split_by_depth(mask: np.ndarray, depth: np.ndarray | None, min_gap: float = 0.03,
                   min_fraction: float = 0.12, min_pixels: int = 200) -> list[np.ndarray]:
    """Split a mask whose valid depths form separate clusters (two boxes at different distances).

    The sorted depths are cut at their widest gap when that gap exceeds `min_gap`
    and both sides hold at least `min_fraction` of the pixels; each side is split
    again until no such gap is left. Pixels without depth go to the nearest part.
    """
    m = mask.astype(bool)
    if depth is None or not m.any():
        return [m]
    vals = depth[m]
    ok = np.isfinite(vals) & (vals > 0)
    if ok.sum() < 2 * min_pixels:
        return [m]
    z = np.sort(vals[ok])
    # ignore the outer 1% (flying pixels at edges)
    lo, hi = int(0.01 * len(z)), int(0.99 * len(z))
    zz = z[lo:hi]
    if len(zz) < 2:
        return [m]
    gaps = np.diff(zz)
    i = int(np.argmax(gaps))
    frac = (i + 1) / len(zz)
    if gaps[i] < min_gap or not (min_fraction <= frac <= 1 - min_fraction):
        return [m]
    cut = 0.5 * (zz[i] + zz[i + 1])
    valid = m & np.isfinite(depth) & (depth > 0)
    near = valid & (depth < cut)
    far = valid & (depth >= cut)
    # pixels without depth: nearest side
    rest = m & ~valid
    if rest.any():
        dn = cv2.distanceTransform((~near).astype(np.uint8), cv2.DIST_L2, 3)
        df = cv2.distanceTransform((~far).astype(np.uint8), cv2.DIST_L2, 3)
        near |= rest & (dn <= df)
        far |= rest & (dn > df)
    out: list[np.ndarray] = []
    for part in (near, far):
        n, lbl, stats, _ = cv2.connectedComponentsWithStats(part.astype(np.uint8), connectivity=8)
        for k in range(1, n):
            if stats[k, cv2.CC_STAT_AREA] >= min_pixels:
                piece = fill_holes(lbl == k)
                if piece.sum() >= m.sum():      # a ring around the other part, filled: the mask again
                    out.append(piece)           # (cutting it again would never end)
                else:
                    out.extend(split_by_depth(piece, depth, min_gap, min_fraction, min_pixels))
    return out or [m]


def iou(a: np.ndarray, b: np.ndarray) -> float:
    inter = np.logical_and(a, b).sum()
    union = np.logical_or(a, b).sum()
    return float(inter) / float(union) if union else 0.0


def dedupe(masks: list[np.ndarray], max_iou: float = 0.5, min_pixels: int = 200) -> list[np.ndarray]:
    """Drop masks that repeat a larger one (IoU or containment above `max_iou`); then
    give each overlapping pixel to the larger mask so masks are disjoint. Overlaps are
    counted inside the two masks' common bounding box (none outside it: the same counts)."""
    order = sorted(range(len(masks)), key=lambda i: -int(masks[i].sum()))
    kept: list[np.ndarray] = []
    spans: list[tuple[int, int, int, int, int]] = []     # each kept mask's rows, columns and area
    taken = None
    for i in order:
        m = masks[i].astype(bool)
        area = count(m)
        if area < min_pixels:
            continue
        span = _span(m)
        if any(_repeats(m, area, span, k, ks, max_iou) for k, ks in zip(kept, spans)):
            continue
        if taken is not None:
            m = m & ~taken
            area = count(m)
            if area < min_pixels:
                continue
            span = _span(m)
        kept.append(m)
        spans.append((*span, area))
        taken = m.copy() if taken is None else (taken | m)
    return kept


def _span(m: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    if len(rows) == 0:
        return 0, 0, 0, 0
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _repeats(m: np.ndarray, area: int, span: tuple, k: np.ndarray, ks: tuple, max_iou: float) -> bool:
    """Whether `m` repeats kept mask `k`: IoU, or the share of `m` inside `k`, above `max_iou`."""
    y0, y1, x0, x1 = max(span[0], ks[0]), min(span[1], ks[1]), max(span[2], ks[2]), min(span[3], ks[3])
    if y0 >= y1 or x0 >= x1:
        return False
    inter = int(np.logical_and(m[y0:y1, x0:x1], k[y0:y1, x0:x1]).sum())
    union = area + ks[4] - inter
    return (float(inter) / float(union) if union else 0.0) > max_iou or inter > max_iou * area


def to_label_image(masks: list[np.ndarray], shape: tuple[int, int] | None = None) -> np.ndarray:
    """uint16 label image: mask i gets label i + 1; later masks never overwrite earlier ones."""
    if shape is None:
        if not masks:
            raise ValueError("shape is needed when there are no masks")
        shape = masks[0].shape
    out = np.zeros(shape, np.uint16)
    for i, m in enumerate(masks, start=1):
        win = box(m)                    # only the mask's own rows and columns change
        if win is not None:
            sub = out[win]
            sub[(sub == 0) & m[win].astype(bool)] = i
    return out


def from_label_image(labels: np.ndarray) -> list[np.ndarray]:
    return [labels == k for k in np.unique(labels) if k > 0]


def _box(mask: np.ndarray, pad: int = 3) -> tuple[slice, slice] | None:
    ys = np.flatnonzero(mask.any(axis=1))
    if len(ys) == 0:
        return None
    xs = np.flatnonzero(mask.any(axis=0))
    h, w = mask.shape
    return (slice(max(0, ys[0] - pad), min(h, ys[-1] + pad + 1)),
            slice(max(0, xs[0] - pad), min(w, xs[-1] + pad + 1)))


def refine(masks: list[np.ndarray], depth: np.ndarray | None, min_pixels: int = 200,
           min_gap: float = 0.03) -> list[np.ndarray]:
    """The full clean-up every segmenter's output goes through (each mask worked on in its
    bounding box: the same result as on the full frame, several times faster)."""
    out: list[np.ndarray] = []
    for m in masks:
        sl = _box(np.asarray(m, bool))
        if sl is None:
            continue
        sub = clean_mask(m[sl], min_pixels)
        if not sub.any():
            continue
        dsub = depth[sl] if depth is not None else None
        for part in split_by_depth(sub, dsub, min_gap=min_gap, min_pixels=min_pixels):
            part = clean_mask(part, min_pixels, open_px=0)
            if part.any():
                full = np.zeros(m.shape, bool)
                full[sl] = part
                out.append(full)
    return dedupe(out, min_pixels=min_pixels)


def grow_on_plane(masks: list[np.ndarray], depth: np.ndarray | None, camera, steps: int = 6,
                  tol: float = 0.005, rgb: np.ndarray | None = None,
                  allowed: np.ndarray | None = None) -> list[np.ndarray]:
    """Grow each mask pixel by pixel onto neighbours that lie on its face plane.

    Depth-jump and normal boundaries leave a band of a few pixels around each
    face unclaimed (smoothing, holes at edges); this gives back the pixels that
    belong to the face, so sizes and IoU are not biased low. No pixel is taken
    from another mask.
    """
    if depth is None or not masks:
        return masks
    h, w = depth.shape
    valid = np.isfinite(depth) & (depth > 0)
    if allowed is not None:
        valid = valid & allowed
    if rgb is not None:
        gray = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY), (3, 3), 0)
        edge = cv2.Canny(gray, 40, 110) > 0
    else:
        edge = np.zeros((h, w), bool)
    taken = np.zeros((h, w), bool)
    for m in masks:
        taken |= m
    free = valid & ~taken
    out = []
    for m in masks:
        m = m.astype(bool)
        plane = _face_plane(*box_nonzero(m, valid), depth, camera, tol)
        if plane is None:
            out.append(m)
            continue
        out.append(_grow_one(m, plane, depth, camera, free, edge, steps, tol))
    # pixels claimed by two grown masks go to neither (they were a boundary)
    claims = np.zeros((h, w), np.int32)
    for o in out:
        claims += o
    once = claims == 1
    return [o & (once | m) for o, m in zip(out, masks)]


def _face_plane(ys: np.ndarray, xs: np.ndarray, depth: np.ndarray, camera,
                tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """(centre, normal, rows, cols) of the plane fitted (SVD, outliers beyond `tol` or 3x the
    median residual dropped) to a sample of at most ~3000 of the pixels (rows `ys`, columns `xs`,
    row by row), the sample's rows and columns; None with fewer than 30 pixels."""
    if len(xs) < 30:
        return None
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    step = max(1, len(xs) // 3000)
    ys, xs = ys[::step], xs[::step]
    z = depth[ys, xs].astype(np.float64)
    p = np.stack([(xs - cx) / fx * z, (ys - cy) / fy * z, z], axis=1)
    c = np.median(p, axis=0)
    q = p - c
    _, _, vt = np.linalg.svd(q, full_matrices=False)
    n = vt[2]
    res = np.abs(q @ n)
    inl = res < max(tol, 3 * float(np.median(res)))
    if count(inl) > 20:
        p = np.compress(inl, p, axis=0)            # p[inl], 4x faster for rows
        c = p.mean(axis=0)
        _, _, vt = np.linalg.svd(p - c, full_matrices=False)
        n = vt[2]
    return c, n, ys, xs


def _grow_one(m: np.ndarray, plane: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
              depth: np.ndarray, camera, free: np.ndarray, edge: np.ndarray, steps: int,
              tol: float) -> np.ndarray:
    """The mask grown `steps` times by one pixel onto `free` pixels within `tol` of its plane,
    entering a colour-edge pixel but not passing it; holes filled."""
    c, n, ys, xs = plane
    h, w = depth.shape
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    k = np.ones((3, 3), np.uint8)
    y0, y1 = max(0, ys.min() - steps - 1), min(h, ys.max() + steps + 2)
    x0, x1 = max(0, xs.min() - steps - 1), min(w, xs.max() + steps + 2)
    sub = m[y0:y1, x0:x1].copy()
    zz = depth[y0:y1, x0:x1].astype(np.float64)
    uu = (np.arange(x0, x1) - cx) / fx
    vv = (np.arange(y0, y1) - cy) / fy
    dist = np.abs(n[0] * (uu[None, :] * zz - c[0]) + n[1] * (vv[:, None] * zz - c[1]) + n[2] * (zz - c[2]))
    ok = free[y0:y1, x0:x1] & (dist < tol)
    stop = edge[y0:y1, x0:x1]
    for _ in range(steps):
        # growth may enter a colour-edge pixel (the true outline) but not pass it
        grown = (cv2.dilate((sub & ~stop).astype(np.uint8), k) > 0) & ok
        new = grown & ~sub
        if not new.any():
            break
        sub |= new
    full = m.copy()
    full[y0:y1, x0:x1] = sub
    return fill_holes(full)


# the borders beyond which a box may stand on or beside the seen ones; below the view of a shelf
# camera lies the floor in front of the shelf (and on the real pallet capture the bottom border
# cuts only the pallet's own edge), so the bottom border is not among them by default
BORDER_SIDES = ("top", "left", "right")


def border_sides(mask: np.ndarray, margin: int = 2, min_pixels: int = 5,
                 sides: tuple[str, ...] = BORDER_SIDES) -> tuple[str, ...]:
    """The image borders among `sides` ("top", "left", "right", "bottom") a mask runs into: its
    face may go on beyond the view, so its size there is only a lower bound."""
    m = np.asarray(mask, bool)
    if min_pixels <= 0 and not m.any():     # (with min_pixels > 0 an empty mask meets no side anyway)
        return ()
    strips = {"top": m[:margin, :], "left": m[:, :margin], "right": m[:, -margin:], "bottom": m[-margin:, :]}
    return tuple(s for s in sides if count(strips[s]) >= min_pixels)


def border_pixels(mask: np.ndarray, side: str, margin: int = 2) -> np.ndarray:
    """The mask's pixels within `margin` of one image border."""
    m = np.asarray(mask, bool)
    sel = np.zeros(m.shape, bool)
    if side == "top":
        sel[:margin, :] = True
    elif side == "bottom":
        sel[-margin:, :] = True
    elif side == "left":
        sel[:, :margin] = True
    elif side == "right":
        sel[:, -margin:] = True
    else:
        raise ValueError(f"unknown image side {side!r}")
    return m & sel
