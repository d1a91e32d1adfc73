"""The picture a person checks perception by: masks, rectangles and box ids over the RGB."""
from __future__ import annotations

import colorsys
from typing import Any, Iterable

import cv2
import numpy as np
from scipy import ndimage

from shelfpick.perception.pixels import hull_candidates


def palette(n: int) -> np.ndarray:
    """n distinct saturated RGB colours (golden-ratio hues), deterministic."""
    return np.array([[int(255 * c) for c in colorsys.hsv_to_rgb((i * 0.618034) % 1.0, 0.85, 0.95)]
                     for i in range(max(n, 1))], np.uint8)


def box_names(boxes: Iterable[Any]) -> dict[int, str]:
    """Mask label -> the id the overlay writes on it: the box's id, with ' ?' on a face perception
    doubts (`Box.contradicted`), for every box that has a mask."""
    return {b.mask_label: b.id + (" ?" if b.contradicted else "") for b in boxes if b.mask_label}


def draw_overlay(rgb: np.ndarray, labels: np.ndarray, names: dict[int, str] | None = None,
                 alpha: float = 0.45) -> np.ndarray:
    """RGB uint8 image: each label tinted, its min-area rectangle outlined and its box id written."""
    out = rgb.copy()
    ids = _present(labels)
    if not ids:
        return out
    cols = palette(max(ids) + 1)
    if out.ndim == 3 and out.shape[2] == 3 and out.dtype == np.uint8 and labels.dtype.kind in "ui" \
            and int(labels.min()) >= 0 and 0 <= alpha <= 1:
        out = _tinted(out, labels, cols, alpha)
    else:
        sel = labels > 0
        out[sel] = (out[sel] * (1 - alpha) + cols[labels[sel]] * alpha).astype(np.uint8)
    boxes = ndimage.find_objects(labels) if labels.dtype.kind in "ui" and max(ids) < 1 << 20 else None
    for k in ids:
        pts = _label_points(labels, k, None if boxes is None else boxes[k - 1])
        if pts is None:
            continue
        rect = cv2.minAreaRect(pts)
        corners = cv2.boxPoints(rect).astype(np.int32)
        col = tuple(int(c) for c in cols[k])
        cv2.polylines(out, [corners], True, col, 2, cv2.LINE_AA)
        text = (names or {}).get(k, str(k))
        cx, cy = (int(v) for v in rect[0])
        # ids readable where the image is shown scaled down (the console's side panel): a text
        # height of about 1/20 of the image width
        scale = max(0.6, out.shape[1] / 520)
        thick = max(2, round(2 * scale))
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        org = (cx - tw // 2, cy + th // 2)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 3, cv2.LINE_AA)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return out


def _tinted(rgb: np.ndarray, labels: np.ndarray, cols: np.ndarray, alpha: float) -> np.ndarray:
    """`rgb[sel] * (1 - alpha) + cols[labels[sel]] * alpha` as uint8 where sel = labels > 0 (rgb
    elsewhere): per channel a table of that very float64 sum for every value and label (label 0:
    the value), read at each pixel, instead of the sums of ~150000 pixels x 3 channels a frame."""
    k = len(cols)
    at = rgb.astype(np.intp) * k
    at += labels[..., None]
    out = np.empty_like(rgb)
    for c in range(3):
        table = (np.arange(256, dtype=np.uint8)[:, None] * (1 - alpha) + cols[None, :, c] * alpha).astype(np.uint8)
        table[:, 0] = np.arange(256)
        out[..., c] = table.ravel().take(at[..., c])
    return out


def _present(labels: np.ndarray) -> list[int]:
    """The labels > 0 in the image, ascending (np.unique's, by a count instead of a sort of the
    whole image where the labels are small non-negative integers)."""
    flat = labels.ravel()
    if labels.dtype.kind in "ui" and flat.size and 0 <= int(flat.min()) and int(flat.max()) < 1 << 20:
        return [int(k) for k in np.flatnonzero(np.bincount(flat)) if k > 0]
    return [int(k) for k in np.unique(labels) if k > 0]


def _label_points(labels: np.ndarray, k: int, box: tuple[slice, slice] | None) -> np.ndarray | None:
    """The points of label k its min-area rectangle needs (`pixels.hull_candidates`), found inside
    the label's bounding box `box` (the whole image without one) and shifted back."""
    if box is None:
        return hull_candidates(labels == k)
    pts = hull_candidates(labels[box] == k)
    if pts is not None:
        pts += np.array([box[1].start, box[0].start], np.int32)
    return pts


UNEXPLAINED_RGB = (128, 128, 128)


def draw_unexplained(rgb: np.ndarray, labels: np.ndarray, names: list[str], alpha: float = 0.35) -> np.ndarray:
    """RGB uint8 image: each region of unexplained matter (label k+1 = names[k]) greyed, hatched
    with diagonal lines, outlined, and its id written with a '?': matter that is there whatever
    the boxes say, told apart from every box's colour."""
    out = rgb.copy()
    sel = labels > 0
    if not sel.any():
        return out
    grey = np.asarray(UNEXPLAINED_RGB, np.float32)
    out[sel] = (out[sel] * (1 - alpha) + grey * alpha).astype(np.uint8)
    h, w = labels.shape
    step = max(6, w // 60)
    yy, xx = np.mgrid[0:h, 0:w]
    hatch = sel & (((xx + yy) % step) < max(1, step // 4))
    out[hatch] = (40, 40, 40)
    scale = max(0.5, w / 640)
    thick = max(1, round(2 * scale))
    written: list[tuple[int, int, int, int]] = []
    for k, name in enumerate(names, start=1):
        m = (labels == k).astype(np.uint8)
        contours, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not contours:
            continue
        cv2.drawContours(out, contours, -1, (255, 255, 255), thick + 1, cv2.LINE_AA)
        cv2.drawContours(out, contours, -1, (30, 30, 30), thick, cv2.LINE_AA)
        text = f"{name}?"
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        org = name_spot(m, (tw, th), written)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 3, cv2.LINE_AA)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return out


def name_spot(mask: np.ndarray, size: tuple[int, int], written: list[tuple[int, int, int, int]]) -> tuple[int, int]:
    """Where a region's name is written (the text's bottom-left): centred on the region's most
    inner pixel, not on its bounding box's centre, which an L-shaped region or a thin strip beside
    another does not contain; moved a line down or up, nearest first, off every name in `written`
    (x0, y0, x1, y1; the chosen one is added), and kept in the image."""
    h, w = mask.shape
    tw, th = size
    x, y, bw, bh = cv2.boundingRect(mask)          # the transform over the region's box only
    dist = cv2.distanceTransform(np.pad(mask[y:y + bh, x:x + bw], 1), cv2.DIST_L2, 3)[1:-1, 1:-1]
    cy, cx = np.unravel_index(int(np.argmax(dist)), dist.shape)
    cy, cx = cy + y, cx + x
    step, rect = th + max(4, th // 2), (0, 0, 0, 0)
    for shift in (0, 1, -1, 2, -2, 3, -3):
        x0 = int(min(max(cx - tw // 2, 0), max(w - tw, 0)))
        y1 = int(min(max(cy + th // 2 + shift * step, th), h - 1))
        rect = (x0 - 2, y1 - th - 2, x0 + tw + 2, y1 + 4)
        if not any(rect[0] < o[2] and o[0] < rect[2] and rect[1] < o[3] and o[1] < rect[3] for o in written):
            break
    written.append(rect)
    return rect[0] + 2, rect[3] - 4
