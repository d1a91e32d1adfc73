"""The seam between two stacked masks moved onto the depth step between the cartons' fronts.

Where cartons carry a coloured band near an edge, the segmenter can take the band's edge, a
strong colour line right across the face, for the boundary between two stacked cartons, and the
faint seam a few centimetres away for nothing: one mask then holds a strip of the carton below or
above it (`labels` 31056: five 50x17 cm cartons of one print measured 14-18 cm high, 3-8 cm too
low; 31032: a 20 cm cube 3 cm off). Where the two cartons' fronts are not flush, the depth says
where the seam is whatever the print says: the step between the two fronts. A seam is moved onto
that step when the step lies off it (`step_offset`): between two masks that meet along most of
their widths (`sits_on`), within `MAX_SHIFT` of the shorter one's height. Seams between flush
fronts (no step) stay where the segmenter put them.
"""
from __future__ import annotations

import warnings

import numpy as np

MAX_SHIFT = 0.35    # a seam moves by at most this share of the shorter mask's height
STEP_M = 0.015      # m: a depth step between two cartons' fronts ...
STEP_HALF = 3       # ... measured over this many rows either side of a row
MIN_SHARED = 0.8    # two masks meet across at least this share of the narrower one's width
MIN_WIDTH_RATIO = 0.85   # ... and are this alike in width
GAP_PX = 3          # rows between one mask's bottom edge and the next one's top edge, or
MAX_GAP = 0.25      # ... up to this share of the shorter mask's height (a band left to neither mask)


def _extent(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(top row, bottom row, left column, right column) of a mask, None if empty."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if not len(rows):
        return None
    return int(rows[0]), int(rows[-1]), int(cols[0]), int(cols[-1])


def _edges(mask: np.ndarray, x0: int, x1: int) -> tuple[np.ndarray, np.ndarray]:
    """(top row, bottom row) of the mask in each column x0..x1 (-1 where the column is empty)."""
    sub = mask[:, x0:x1 + 1]
    has = sub.any(axis=0)
    top = np.where(has, np.argmax(sub, axis=0), -1)
    bottom = np.where(has, sub.shape[0] - 1 - np.argmax(sub[::-1], axis=0), -1)
    return top, bottom


def _most_gap(eu: tuple, el: tuple) -> int:
    """The most rows one mask's bottom edge may lie above the next one's top edge for them to meet."""
    return max(GAP_PX, int(MAX_GAP * min(eu[1] - eu[0], el[1] - el[0]))) + 1


def _meeting(upper: np.ndarray, lower: np.ndarray, eu: tuple, el: tuple
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(columns, upper's bottom row, lower's top row) where `lower`'s top edge lies within
    `GAP_PX` rows (or `MAX_GAP` of the shorter mask's height) below `upper`'s bottom edge."""
    x0, x1 = max(eu[2], el[2]), min(eu[3], el[3])
    if x1 < x0:
        return np.zeros(0, int), np.zeros(0, int), np.zeros(0, int)
    _, bottom = _edges(upper, x0, x1)
    top, _ = _edges(lower, x0, x1)
    most = _most_gap(eu, el)
    gap = top - bottom
    ok = (bottom >= 0) & (top >= 0) & (gap >= 1) & (gap <= most)
    return np.arange(x0, x1 + 1)[ok], bottom[ok], top[ok]


def sits_on(upper: np.ndarray, lower: np.ndarray, eu: tuple, el: tuple) -> bool:
    """Whether mask `upper` meets mask `lower` along its bottom edge (`_meeting`) across at least
    `MIN_SHARED` of the narrower mask's width, the two about as wide (`MIN_WIDTH_RATIO`)."""
    wu, wl = eu[3] - eu[2] + 1, el[3] - el[2] + 1
    need = MIN_SHARED * min(wu, wl)
    if min(wu, wl) < MIN_WIDTH_RATIO * max(wu, wl) or min(eu[3], el[3]) - max(eu[2], el[2]) + 1 < need \
            or el[0] > eu[1] + _most_gap(eu, el):
        return False                     # bounding boxes too unlike, or too far apart, to meet
    return len(_meeting(upper, lower, eu, el)[0]) >= need


def stacked_pairs(masks: list[np.ndarray]) -> list[tuple[int, int]]:
    """(upper, lower) for every mask resting on exactly one mask that rests under no other
    (`sits_on`): a seam between two stacked cartons, not a carton across two; top first."""
    ext = [_extent(m) for m in masks]
    below: dict[int, list[int]] = {}
    above: dict[int, list[int]] = {}
    for i, e in enumerate(ext):
        for j, f in enumerate(ext):
            if j != i and e is not None and f is not None and f[0] > e[0] and sits_on(masks[i], masks[j], e, f):
                below.setdefault(i, []).append(j)
                above.setdefault(j, []).append(i)
    pairs = [(i, js[0]) for i, js in below.items() if len(js) == 1 and len(above[js[0]]) == 1]
    return sorted(pairs, key=lambda p: ext[p[0]][0])     # top first: a column's seams in order


def step_offset(masks: list[np.ndarray], upper: int, lower: int, depth: np.ndarray,
                meet: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> int | None:
    """Rows from the seam between two stacked masks down to the depth step between the two
    cartons' fronts (negative: up), where the step lies off the seam: the row of the largest
    change (over `STEP_HALF` rows either side) of the depth's median across the seam's columns,
    within `MAX_SHIFT` of the shorter mask's height, of at least `STEP_M` and at least twice the
    change at the seam itself. None where no such step is found (fronts on one plane, a step on
    the seam already). `meet`: where the two meet (`_meeting`; found here when None)."""
    eu, el = _extent(masks[upper]), _extent(masks[lower])
    assert eu is not None and el is not None
    cols, bottom, top = meet if meet is not None else _meeting(masks[upper], masks[lower], eu, el)
    if len(cols) < 10:
        return None
    reach = int(MAX_SHIFT * min(eu[1] - eu[0], el[1] - el[0]))
    seam = (bottom + top) // 2
    k = STEP_HALF
    rows = np.clip(seam[None, :] + np.arange(-reach - k, reach + k + 1)[:, None], 0, depth.shape[0] - 1)
    ours = (masks[upper] | masks[lower])[rows, cols[None, :]] | ((rows > bottom) & (rows < top))
    z = depth[rows, cols[None, :]].astype(float)
    z[~ours | ~(z > 0)] = np.nan
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)    # a row with no depth: NaN, no change there
        med = np.nanmedian(z, axis=1)
    change = np.nan_to_num(np.abs(med[2 * k:] - med[:-2 * k]))   # at offsets -reach..reach
    j = int(np.argmax(change))       # the first of a run of equal changes: up to STEP_HALF - 1 rows high
    if change[j] < STEP_M or change[j] < 2 * change[reach] or abs(j - reach) < 2:
        return None
    return j - reach


def moved_seam(masks: list[np.ndarray], upper: int, lower: int, rows: int,
               meet: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None) -> list[np.ndarray]:
    """The masks with the seam between `upper` and `lower` moved `rows` down (negative: up): in
    each column the two meet (`meet`, from `_meeting`), the pixels between the old seam and the
    new one, and the rows between them that no mask held, go to the mask now on their side.
    Other masks untouched."""
    if meet is None:
        eu, el = _extent(masks[upper]), _extent(masks[lower])
        assert eu is not None and el is not None
        meet = _meeting(masks[upper], masks[lower], eu, el)
    cols, bottom, top = meet
    out = list(masks)
    if not len(cols):
        return out
    held = np.logical_or.reduce(masks)[:, cols]
    grid = np.arange(held.shape[0])[:, None]
    seam = (bottom + top) // 2 + rows                   # the new seam: the upper mask's last row
    sub_u, sub_l = masks[upper][:, cols], masks[lower][:, cols]
    ours = sub_u | sub_l | (~held & (grid > bottom) & (grid < top))
    to_lower = ours & (grid > seam) & (grid < top)
    to_upper = ours & (grid <= seam) & (grid > bottom)
    out[upper], out[lower] = masks[upper].copy(), masks[lower].copy()
    out[upper][:, cols] = (sub_u & ~to_lower) | to_upper
    out[lower][:, cols] = (sub_l & ~to_upper) | to_lower
    return out


def depth_seams(masks: list[np.ndarray], depth: np.ndarray) -> tuple[list[np.ndarray], list[tuple[int, int, int]]]:
    """(masks, moves): every seam between two stacked masks (`stacked_pairs`) moved onto the depth
    step between the cartons' fronts where it lies off it (`step_offset`); moves: (upper, lower,
    rows moved down)."""
    moves = []
    for u, l in stacked_pairs(masks):
        eu, el = _extent(masks[u]), _extent(masks[l])     # as they stand after the seams moved above
        assert eu is not None and el is not None
        meet = _meeting(masks[u], masks[l], eu, el)
        off = step_offset(masks, u, l, depth, meet)
        if off is not None:
            masks = moved_seam(masks, u, l, off, meet)
            moves.append((u, l, off))
    return masks, moves

