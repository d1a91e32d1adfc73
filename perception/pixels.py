"""Pixel counts and coordinates of 2-D masks, the same numbers as numpy's own calls, faster.

Why: `perceive` asks for the pixels of full 640x480 masks hundreds of times a frame. numpy's 2-D
`np.nonzero` took ~1 ms for a 20000-pixel mask in a 640x480 frame where the flat indices split
into rows and columns took 0.15 ms; `mask.sum()` of a bool image adds it up as integers
(~110 us a frame) where `np.count_nonzero` counts it (~17 us). Same values, same order, same
dtype (int64 coordinates); only the time differs.
"""
from __future__ import annotations

import numpy as np


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
