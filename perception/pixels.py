"""Pixel counts and coordinates of 2-D masks, the same numbers as numpy's own calls, faster.

Why: `perceive` asks for the pixels of full 640x480 masks hundreds of times a frame. numpy's 2-D
`np.nonzero` took ~1 ms for a 20000-pixel mask in a 640x480 frame where the flat indices split
into rows and columns took 0.15 ms; `mask.sum()` of a bool image adds it up as integers
(~110 us a frame) where `np.count_nonzero` counts it (~17 us). Same values, same order, same
dtype (int64 coordinates); only the time differs.
"""
from __future__ import annotations

import numpy as np
from scipy import ndimage


def nonzero(mask: np.ndarray) -> tuple[np.ndarray, ...]:
    """`np.nonzero(mask)`: the rows and columns of a 2-D array's non-zero entries, row by row,
    from its flat indices (any other shape: numpy's own)."""
    a = np.asarray(mask)
    if a.ndim != 2 or a.shape[1] == 0:
        return np.nonzero(a)
    return np.divmod(np.flatnonzero(a), a.shape[1])


def count(mask: np.ndarray) -> int:
    """`int(mask.sum())` of a bool mask: its number of True pixels."""
    return int(np.count_nonzero(mask))


def label_masks(labels: np.ndarray, n: int) -> list[np.ndarray]:
    """`[labels == k for k in range(1, n + 1)]` of an integer label image, each compared only
    within its label's bounding box (`ndimage.find_objects`), the rest of the frame left False:
    the same masks, without n passes over the whole frame."""
    boxes = ndimage.find_objects(labels, max_label=n) if n > 0 else []
    out = []
    for k, win in enumerate(boxes, start=1):
        m = np.zeros(labels.shape, bool)
        if win is not None:
            m[win] = labels[win] == k
        out.append(m)
    return out


def label_sums(values: np.ndarray, labels: np.ndarray, index: np.ndarray) -> np.ndarray:
    """`scipy.ndimage.sum(values, labels, index)` for non-negative integer labels: the float64 sum
    of `values` over each label of `index` (0 for a label not present), by the one weighted
    `np.bincount` scipy itself ends in, without its label range checks and pixel counts. Where
    label 0 is not asked for, only the labelled pixels go in (most of a frame is background, and
    this ran 12 times a frame): bincount adds each label's values one by one in pixel order, and
    that order and those values stay the same, so the sums do too."""
    idx = np.asarray(index, np.intp)
    lab, vals = np.asarray(labels), np.asarray(values)
    n = max(int(idx.max()) + 1 if idx.size else 0, 1)
    if idx.size and idx.min() > 0 and lab.shape == vals.shape:
        on = lab != 0
        return np.bincount(lab[on], weights=vals[on], minlength=n)[idx]
    sums = np.bincount(lab.ravel(), weights=vals.ravel(), minlength=n)
    return sums[idx]


def label_percentiles(values: np.ndarray, labels: np.ndarray, index: np.ndarray, q: float,
                      default: float = 0.0) -> np.ndarray:
    """`scipy.ndimage.labeled_comprehension(values, labels, index, lambda v: np.percentile(v, q),
    float, default)` for non-negative integer labels: each label's values gathered by one stable
    sort of the labelled pixels, then numpy's own percentile of each group (the same numbers: a
    percentile does not depend on the order of its values)."""
    idx = np.asarray(index, np.intp)
    out = np.full(idx.shape, default, float)
    if not idx.size:
        return out
    lab = np.asarray(labels).ravel()
    n = int(idx.max()) + 1
    sel = np.flatnonzero((lab > 0) & (lab < n)) if idx.min() > 0 else np.flatnonzero(lab < n)
    grouped = lab[sel]
    vals = np.asarray(values).ravel()[sel[np.argsort(grouped, kind="stable")]]
    counts = np.bincount(grouped, minlength=n)
    ends = np.cumsum(counts)
    for k, i in enumerate(idx):
        if counts[i]:
            out[k] = np.percentile(vals[ends[i] - counts[i]:ends[i]], q)
    return out


def hull_candidates(mask: np.ndarray) -> np.ndarray | None:
    """The pixels of a 2-D mask that can lie on its convex hull, as `cv2.findNonZero` gives points
    (N x 1 x 2 int32, x then y) and in its row-major order (a subsequence of it), None when empty:
    every pixel of its first and last row, the first and last pixel of each row between.

    Why: `cv2.minAreaRect` of a mask's pixels sorts them all to find their hull (0.6-0.8 ms a
    mask on these frames); the hull of these few is the same polygon, and OpenCV's `convexHull`
    (which `minAreaRect` runs first) orders its output by the points' geometry and their relative
    input order only, which a row-major subsequence keeps, so `minAreaRect` of them returns the
    same rectangle (tests/perception/test_pixels.py holds it to that on thousands of shapes)."""
    m = np.asarray(mask, bool)
    rows = np.flatnonzero(m.any(axis=1))
    if not len(rows):
        return None
    cols = np.flatnonzero(m.any(axis=0))
    y0, y1, x0 = int(rows[0]), int(rows[-1]), int(cols[0])
    sub = m[y0:y1 + 1, x0:int(cols[-1]) + 1]
    top = np.flatnonzero(sub[0])
    xs, ys = [top], [np.zeros(len(top), np.intp)]
    if y1 > y0:
        inner = sub[1:-1]
        has = np.flatnonzero(inner.any(axis=1))
        s = inner[has]
        left = s.argmax(axis=1)
        right = s.shape[1] - 1 - s[:, ::-1].argmax(axis=1)
        pair = np.stack([left, right], axis=1).ravel()
        keep = np.ones(len(pair), bool)
        keep[1::2] = right != left
        bottom = np.flatnonzero(sub[-1])
        xs += [pair[keep], bottom]
        ys += [np.repeat(has + 1, 2)[keep], np.full(len(bottom), y1 - y0, np.intp)]
    x = np.concatenate(xs) + x0
    y = np.concatenate(ys) + y0
    return np.stack([x, y], axis=1).astype(np.int32).reshape(-1, 1, 2)
