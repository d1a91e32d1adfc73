"""A mask's bounding box, so the repairs' pixel tests run on the few rows and columns a mask
covers instead of the whole 640x480 frame.

Why: the repairs ask of each mask, again and again, its pixels with depth, the pixels within the
join gap of it (a 25x25 dilation) and whether another mask touches those; on the full frame each
is a pass over 307200 pixels (a dilation ~0.5 ms), on the box a few thousand. Same values, same
order (row by row) as the full-frame calls: a pixel outside the box is never in the mask, and a
pixel further than the gap from the box is never within the gap of it.
"""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.pixels import nonzero

Window = tuple[slice, slice]


def box(mask: np.ndarray, pad: int = 0) -> Window | None:
    """The rows and columns holding the mask's pixels, `pad` more on each side within the frame;
    None for an empty mask."""
    rows = np.flatnonzero(mask.any(axis=1))
    if not len(rows):
        return None
    y0, y1 = int(rows[0]), int(rows[-1]) + 1
    cols = np.flatnonzero(mask[y0:y1].any(axis=0))
    x0, x1 = int(cols[0]), int(cols[-1]) + 1
    h, w = mask.shape
    return slice(max(0, y0 - pad), min(h, y1 + pad)), slice(max(0, x0 - pad), min(w, x1 + pad))


def box_nonzero(mask: np.ndarray, also: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """`pixels.nonzero(mask & also)` (`also` None: of the mask alone), found within the mask's box:
    the same rows and columns (int64) in the same order."""
    win = box(mask)
    if win is None:
        empty = np.zeros(0, np.int64)
        return empty, empty.copy()
    sub = mask[win] if also is None else mask[win] & also[win]
    ys, xs = nonzero(sub)
    return ys + win[0].start, xs + win[1].start


class Near:
    """The pixels within `gap` px (a square) of a mask: `cv2.dilate` of its box grown by the gap,
    the rest of the frame empty."""

    def __init__(self, mask: np.ndarray, kernel: np.ndarray, gap: int) -> None:
        self.shape = mask.shape
        self.win = box(mask, gap)
        self.pixels = None if self.win is None else cv2.dilate(mask[self.win].astype(np.uint8), kernel) > 0

    def touches(self, other: np.ndarray) -> bool:
        """`(near & other).any()` of the full-frame dilation."""
        return self.pixels is not None and bool((self.pixels & other[self.win]).any())

    def full(self) -> np.ndarray:
        """The full-frame dilation (bool)."""
        out = np.zeros(self.shape, bool)
        if self.pixels is not None:
            out[self.win] = self.pixels
        return out
