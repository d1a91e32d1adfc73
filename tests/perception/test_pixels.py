"""`perception.pixels` gives exactly numpy's numbers (it exists only for speed)."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.pixels import count, nonzero


def _masks() -> list[np.ndarray]:
    rng = np.random.default_rng(7)
    full = rng.random((48, 64)) < 0.3
    square = np.zeros((48, 64), bool)
    square[10:30, 5:40] = True
    return [full, square, np.zeros((48, 64), bool), np.ones((3, 5), bool),
            full[5:40:2, 3:50],                       # a strided view, not contiguous
            (rng.random((20, 30)) * 3).astype(np.uint8),   # not bool: non-zero entries
            np.zeros((4, 0), bool)]


@pytest.mark.parametrize("mask", _masks(), ids=["random", "square", "empty", "small", "view", "uint8", "no columns"])
def test_nonzero_is_numpys_rows_and_columns_in_its_order(mask):
    want, got = np.nonzero(mask), nonzero(mask)
    assert len(got) == 2
    for w, g in zip(want, got):
        assert g.dtype == w.dtype
        np.testing.assert_array_equal(g, w)


def test_nonzero_of_other_shapes_is_numpys():
    a = np.array([0, 3, 0, 1])
    np.testing.assert_array_equal(nonzero(a)[0], np.nonzero(a)[0])


@pytest.mark.parametrize("mask", _masks()[:5], ids=["random", "square", "empty", "small", "view"])
def test_count_is_the_bool_masks_sum(mask):
    assert count(mask) == int(mask.sum()) and isinstance(count(mask), int)
