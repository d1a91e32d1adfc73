"""A mask whose min-area rectangle lies over another mask that is not in front of it is no front.

Its face would stand where the camera sees another surface at its depth or behind it: the mask is
two cartons (an L of one print over a piece of a third; issue 31, tuning look `labels`), and the
two faces built from it overlap past any repair, so no sample world can be built. Found here,
cut in `boxes.split_merged` by one straight row or column into parts free of the other mask.
"""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.scene import Camera

# a mask whose rectangle lies over at least this share of another mask's pixels ...
COVER_SHARE = 0.5
# ... where that mask is not this far in front of it (a box in front may hide part of a face):
# its rectangle is no front face, for the other mask's surface would be hidden behind it
COVER_AHEAD = 0.02


def _rect_px(m: np.ndarray) -> tuple[np.ndarray, tuple[slice, slice]]:
    """The filled min-area rectangle of a mask's pixels, on the crop (returned) around it; fitted
    to the outline on the mask's crop (the outline holds the hull: the same rectangle, faster)."""
    sy, sx, _ = extent(m)
    crop = np.ascontiguousarray(m[sy, sx], np.uint8)
    contours, _ = cv2.findContours(crop, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
    pts = (np.concatenate(contours).reshape(-1, 2) + (int(sx.start), int(sy.start))).astype(np.float32)
    corners = cv2.boxPoints(cv2.minAreaRect(pts))
    x0, y0 = np.floor(corners.min(axis=0)).astype(int)
    x1, y1 = np.ceil(corners.max(axis=0)).astype(int)
    x0, y0 = max(x0, 0), max(y0, 0)
    x1, y1 = min(x1 + 1, m.shape[1]), min(y1 + 1, m.shape[0])
    poly = np.zeros((max(y1 - y0, 0), max(x1 - x0, 0)), np.uint8)
    cv2.fillPoly(poly, [np.round(corners - (x0, y0)).astype(np.int32)], 1)
    return poly.astype(bool), (slice(y0, y1), slice(x0, x1))


def _share_under(m: np.ndarray, others: list[np.ndarray]) -> float:
    """The largest share of any of `others`' pixels that `m`'s rectangle lies over."""
    rect, (sy, sx) = _rect_px(m)
    return max((float(np.count_nonzero(rect & o[sy, sx])) / max(int(np.count_nonzero(o)), 1)
                for o in others), default=0.0)


Extent = tuple[slice, slice, int]     # a mask's bounding rows, columns and pixel count


def extent(m: np.ndarray) -> Extent:
    """The rows and columns a mask spans, and its pixel count (empty slices for an empty mask)."""
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    if not rows.size:
        return slice(0, 0), slice(0, 0), 0
    return slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1), int(np.count_nonzero(m))


class Fronts:
    """Each mask's median distance behind the shelf's front plane (shelf y, m; nan without depth),
    computed when first asked (most masks' rectangles lie over no other mask)."""

    def __init__(self, masks: list[np.ndarray], extents: list[Extent], depth: np.ndarray, camera: Camera):
        self.masks, self.extents, self.depth, self.camera = masks, extents, depth, camera
        self.ys: dict[int, float] = {}

    def __call__(self, j: int) -> float:
        if j not in self.ys:
            from shelfpick.perception.geometry import point_map

            sy, sx, _ = self.extents[j]
            d = self.depth[sy, sx]
            sel = np.asarray(self.masks[j], bool)[sy, sx] & np.isfinite(d) & (d > 0)
            pts = point_map(self.camera, self.depth)[sy, sx]
            self.ys[j] = float(np.median(pts[sel][:, 1])) if sel.any() else float("nan")
        return self.ys[j]


def covered_masks(m: np.ndarray, masks: list[np.ndarray], extents: list[Extent], front: Fronts,
                  i: int, min_fill: float) -> list[int]:
    """The masks (indices) that mask `i`'s min-area rectangle lies over by `COVER_SHARE` of their
    pixels and that are not `COVER_AHEAD` in front of it. Its face would stand where the camera
    sees another surface at its depth or behind it: the mask is no rectangle but two cartons
    (an L of one print over a piece of a third, issue 31, tuning look `labels`), and the two
    faces built from it overlap past any repair. A mask that fills its own rectangle less than
    `min_fill` (`boxes.MIN_RECT_FILL`) is no face (it is dropped, or cut itself) and contradicts nothing."""
    from shelfpick.perception.repairs.merged import rect_fill

    rect, (ry, rx) = _rect_px(m)
    out = []
    for j, (oy, ox, n) in enumerate(extents):
        y0, y1, x0, x1 = max(ry.start, oy.start), min(ry.stop, oy.stop), max(rx.start, ox.start), min(rx.stop, ox.stop)
        if j == i or not n or y1 - y0 <= 0 or x1 - x0 <= 0 or (y1 - y0) * (x1 - x0) < COVER_SHARE * n:
            continue
        under = rect[y0 - ry.start:y1 - ry.start, x0 - rx.start:x1 - rx.start] & \
            np.asarray(masks[j], bool)[y0:y1, x0:x1]
        if np.count_nonzero(under) >= COVER_SHARE * n and front(j) >= front(i) - COVER_AHEAD \
                and rect_fill(masks[j]) >= min_fill:
            out.append(j)
    return out


def uncovered_parts(m: np.ndarray, under: list[np.ndarray], min_px: int, min_fill: float,
                    stride: int = 2) -> list[np.ndarray]:
    """`m` cut by one straight image row or column into two parts whose rectangles no longer lie
    over the masks `under` (`COVER_SHARE`), each filling its rectangle at least `min_fill`, the
    best-filled cut winning; [m] when there is none. Rows first, and a column must fill better by
    0.02 to win: two cartons of one print merged are most often stacked (on the tuning look the
    row and column cuts of an L fill alike and the row was the true seam, 4 of 4)."""
    from shelfpick.perception.repairs.merged import MIN_PART_SHARE, _largest, rect_fill

    m = np.asarray(m, bool)
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    n = int(np.count_nonzero(m))
    need = max(min_px, MIN_PART_SHARE * n)
    best: tuple[np.ndarray, np.ndarray] | None = None
    best_score = 0.0
    for axis, span in ((0, rows), (1, cols)):
        for c in range(int(span[0]) + stride, int(span[-1]) + 1 - stride, stride):
            a = m.copy()
            if axis == 0:
                a[c:] = False
            else:
                a[:, c:] = False
            a, b = _largest(a), _largest(m & ~a)
            na, nb = int(np.count_nonzero(a)), int(np.count_nonzero(b))
            if na < need or nb < need:
                continue
            fa, fb = rect_fill(a), rect_fill(b)
            score = (na * fa + nb * fb) / n
            if min(fa, fb) < min_fill or score <= best_score + 0.02:
                continue
            if max(_share_under(a, under), _share_under(b, under)) < COVER_SHARE:
                best, best_score = (a, b), score
    return [m] if best is None else list(best)
