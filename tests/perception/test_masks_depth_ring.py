"""masks.split_by_depth on a mask whose near part is a ring around its far part (found on the
`labels` tuning look with a raised segmenter threshold: perceive died of a RecursionError)."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.masks import split_by_depth


def test_a_near_ring_around_a_far_square_ends_instead_of_recursing_forever() -> None:
    depth = np.full((120, 160), 1.0, np.float32)
    depth[40:80, 60:100] = 1.1                      # a far square inside a near ring: 10 cm behind
    mask = np.zeros((120, 160), bool)
    mask[20:100, 40:120] = True
    parts = split_by_depth(mask, depth, min_pixels=50)
    assert 1 <= len(parts) <= 3
    assert all(p.sum() <= mask.sum() for p in parts)
    assert np.logical_or.reduce(parts).sum() >= mask.sum() - 1600   # nothing much lost
