"""Masks that are two boxes, split by geometry alone (no catalogue, no colour): issue 31.

Two failure modes seen on renders we never trained on:
- two boxes at different depths, one behind the other, in one mask: the depth image has a step
  running through it (`depth_step_parts`);
- two boxes of one colour side by side at one depth in one mask whose outline is an L or a step, so
  it fills its rectangle badly and used to be dropped as "not a box front", leaving a hole where two
  boxes stand (`rectangle_parts`: the straight image row or column cut that leaves parts that fill
  their own rectangles).
Both only cut; the parts are measured and checked like any other mask.
"""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

STEP_M = 0.02           # a depth step between two fronts (the judge's boxes stand 1-6 cm proud)
STEP_BASE_PX = 2        # the step is measured between pixels this far either side (flying pixels)
MIN_PART_SHARE = 0.15   # each part holds at least this share of the mask ...
PART_FILL = 0.72        # ... and a rectangle cut's parts fill their own rectangles this well


def _crop(mask: np.ndarray, pad: int) -> tuple[slice, slice]:
    rows = np.flatnonzero(mask.any(axis=1))
    cols = np.flatnonzero(mask.any(axis=0))
    return (slice(max(0, rows[0] - pad), rows[-1] + pad + 1), slice(max(0, cols[0] - pad), cols[-1] + pad + 1))


def _nearest(mask: np.ndarray, seeds: list[np.ndarray]) -> list[np.ndarray]:
    """The mask's pixels given to the nearest seed (every seed lies inside the mask)."""
    dist = np.stack([cv2.distanceTransform((~s).astype(np.uint8), cv2.DIST_L2, 3) for s in seeds])
    owner = np.argmin(dist, axis=0)
    return [mask & (owner == k) for k in range(len(seeds))]


def depth_step_parts(mask: np.ndarray, depth: np.ndarray, min_px: int, step: float = STEP_M) -> list[np.ndarray]:
    """The mask cut along the depth steps (>= `step` m between pixels `STEP_BASE_PX` either side, on
    a 5x5 median of the depth) that run right through it; [mask] when no step separates parts of at
    least `min_px` pixels and `MIN_PART_SHARE` of it. Depth holes never count as a step."""
    mask = np.asarray(mask, bool)
    n = int(mask.sum())
    if n < 2 * min_px:
        return [mask]
    sy, sx = _crop(mask, STEP_BASE_PX + 3)
    m, d = mask[sy, sx], depth[sy, sx]
    mm = cv2.medianBlur(np.clip(np.nan_to_num(d) * 1000, 0, 65535).astype(np.uint16), 5).astype(np.float32) / 1000
    ok = mm > 0
    k = STEP_BASE_PX
    edge = np.zeros_like(m)
    for a, b in (((slice(None), slice(2 * k, None)), (slice(None), slice(None, -2 * k))),
                 ((slice(2 * k, None), slice(None)), (slice(None, -2 * k), slice(None)))):
        jump = (np.abs(mm[a] - mm[b]) >= step) & ok[a] & ok[b]
        mid = (slice(k, -k), slice(None)) if a[0].start else (slice(None), slice(k, -k))
        edge[mid] |= jump
    core = m & ok & ~cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
    count, lab, stats, _ = cv2.connectedComponentsWithStats(core.astype(np.uint8), connectivity=4)
    need = max(min_px, MIN_PART_SHARE * n)
    big = [i for i in range(1, count) if stats[i, cv2.CC_STAT_AREA] >= need]
    if len(big) < 2:
        return [mask]
    seeds = [lab == i for i in big]
    meds = [float(np.median(mm[s])) for s in seeds]
    if max(meds) - min(meds) < step:          # one surface cut by a ridge of noise, not two fronts
        return [mask]
    out = []
    for part in _nearest(m, seeds):
        full = np.zeros_like(mask)
        full[sy, sx] = part
        out.append(full)
    return out


def rect_fill(mask: np.ndarray) -> float:
    """How well a mask fills its min-area rectangle (pixels / rectangle area, the rectangle fitted
    to pixel centres). Fitted to the outline on the mask's crop: the same rectangle as over every
    pixel (the outline holds the hull), several times faster."""
    mask = np.asarray(mask, bool)
    if not mask.any():
        return 0.0
    sy, sx = _crop(mask, 1)
    m = mask[sy, sx].astype(np.uint8)
    n = int(m.sum())
    if n < 3:
        return 0.0
    contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    (_, _), (rw, rh), _ = cv2.minAreaRect(np.concatenate(contours).reshape(-1, 2).astype(np.float32))
    return n / max(rw * rh, 1.0)


def _largest(mask: np.ndarray) -> np.ndarray:
    count, lab, stats, _ = cv2.connectedComponentsWithStats(mask.astype(np.uint8), connectivity=4)
    if count <= 2:
        return mask
    return lab == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))


def trimmed(mask: np.ndarray, px: int = 5) -> np.ndarray:
    """The mask without strands thinner than `px` (a 1-2 px line along a neighbour's edge makes a
    front fill its rectangle badly): opened, its largest part kept."""
    k = cv2.getStructuringElement(cv2.MORPH_RECT, (px, px))
    return _largest(cv2.morphologyEx(np.asarray(mask, np.uint8), cv2.MORPH_OPEN, k).astype(bool))


def rectangle_parts(mask: np.ndarray, min_px: int, budget: int = 3, fill: float = PART_FILL,
                    stride: int = 2) -> list[np.ndarray]:
    """A badly filled mask cut by straight image rows or columns into up to `budget` parts that each
    fill their own rectangle >= `fill` (two boxes of one colour side by side, one taller: an L or a
    step outline); [mask] when no such cut exists. The cut that leaves the best-filled parts wins."""
    mask = np.asarray(mask, bool)
    if budget < 2 or rect_fill(mask) >= fill:
        return [mask]
    sy, sx = _crop(mask, 0)
    m = mask[sy, sx]
    n = int(m.sum())
    need = max(min_px, MIN_PART_SHARE * n)
    best, best_score = None, 0.0
    for axis in (1, 0):       # columns first: on a tie, boxes side by side (both standing on something)
        length = m.shape[axis]
        for c in range(stride, length - stride, stride):
            a = m.copy()
            if axis == 0:
                a[c:] = False
            else:
                a[:, c:] = False
            b = m & ~a
            na, nb = int(a.sum()), int(b.sum())
            if na < need or nb < need:
                continue
            fa, fb = rect_fill(_largest(a)), rect_fill(_largest(b))
            score = (na * fa + nb * fb) / n
            if min(fa, fb) >= 0.5 and score > best_score + 0.02:     # (a tie keeps the earlier cut)
                best, best_score = (a, b), score
    if best is None or best_score <= rect_fill(m) + 0.1:
        return [mask]
    out = []
    for part in best:
        full = np.zeros_like(mask)
        full[sy, sx] = part
        full = _largest(full)
        out.extend(rectangle_parts(full, min_px, budget - 1, fill, stride) if rect_fill(full) < fill else [full])
    if any(rect_fill(p) < 0.5 for p in out):
        return [mask]
    return out


OFF_PLANE_M = 0.012     # a mask pixel this far behind or before its face's plane is not on the face
OFF_PLANE_SHARE = 0.03  # trimmed only when at least this share of the mask is off the plane


def off_plane_trimmed(mask: np.ndarray, centre, normal: np.ndarray, depth: np.ndarray, camera,
                      tol: float = OFF_PLANE_M) -> np.ndarray:
    """The mask without the pixels whose depth point lies off its front face's plane by more than
    `tol` (a box's top face of the same colour seen from above, a strip of the wall beside it); the
    mask itself when few pixels are off it. Pixels without depth stay; the largest part is kept."""
    from shelfpick.perception.geometry import point_map

    mask = np.asarray(mask, bool)
    sy, sx = _crop(mask, 1)
    sub = replace(camera, cx=camera.cx - sx.start, cy=camera.cy - sy.start)   # the crop's own principal point
    d = depth[sy, sx]
    pts = point_map(sub, d)
    dist = (pts - np.asarray(centre, np.float32)) @ np.asarray(normal, np.float32)
    m = mask[sy, sx]
    off = m & (d > 0) & (np.abs(dist) > tol)
    if off.sum() < OFF_PLANE_SHARE * m.sum():
        return mask
    kept = _largest(m & ~off)
    out = np.zeros_like(mask)
    out[sy, sx] = kept
    return out


def top_edge_hidden(mask: np.ndarray, depth: np.ndarray, band: int = 4, step: float = STEP_M,
                    share: float = 0.6) -> bool:
    """Whether something in front hides the face's top edge: above at least `share` of the mask's
    columns, the `band` pixels over its top pixel hold depth closer than the face by `step`."""
    mask = np.asarray(mask, bool)
    cols = np.flatnonzero(mask.any(axis=0))
    if len(cols) < 5:
        return False
    top = np.argmax(mask[:, cols], axis=0)
    inside = depth[np.minimum(top + 3, mask.shape[0] - 1), cols]
    above = np.stack([depth[np.maximum(top - k, 0), cols] for k in range(1, band + 1)])
    valid_above = np.where(above > 0, above, np.inf).min(axis=0)
    ok = (inside > 0) & (top >= band)
    counted = int(ok.sum())
    hidden = int((ok & (valid_above < inside - step)).sum())
    return counted >= 5 and hidden >= share * counted
