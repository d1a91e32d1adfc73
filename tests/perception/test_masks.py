"""Mask clean-up: blobs, holes, depth splits, duplicates, label images."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.masks import clean_mask, dedupe, fill_holes, refine, split_by_depth, to_label_image


def rect(shape, y0, y1, x0, x1):
    m = np.zeros(shape, bool)
    m[y0:y1, x0:x1] = True
    return m


def test_clean_drops_small_blobs_and_fills_holes():
    m = rect((100, 100), 10, 60, 10, 60)
    m[30:35, 30:40] = False          # a label-shaped hole
    m[80:83, 80:83] = True           # a 9-pixel speck
    c = clean_mask(m, min_pixels=50)
    assert c[32, 35] and not c[81, 81]
    assert c.sum() == 50 * 50


def test_fill_holes_keeps_notches_open_to_the_border():
    m = rect((50, 50), 0, 50, 0, 50)
    m[0:10, 20:25] = False           # touches the border: not a hole
    assert not fill_holes(m)[5, 22]


def test_mask_spanning_two_boxes_at_different_depths_is_split():
    shape = (120, 160)
    depth = np.zeros(shape, np.float32)
    depth[:, :80] = 0.95
    depth[:, 80:] = 1.10
    rng = np.random.default_rng(0)
    depth += rng.normal(0, 0.002, shape).astype(np.float32)
    depth[50:55, 60:100] = 0.0       # a hole across the seam
    m = rect(shape, 20, 100, 20, 140)
    parts = split_by_depth(m, depth, min_gap=0.03, min_pixels=100)
    assert len(parts) == 2
    left, right = sorted(parts, key=lambda p: np.nonzero(p)[1].mean())
    assert np.nonzero(left)[1].max() < 80 <= np.nonzero(right)[1].min()
    assert left.sum() + right.sum() == m.sum()  # hole pixels went to one side


def test_one_box_with_noisy_depth_is_not_split():
    shape = (80, 80)
    rng = np.random.default_rng(1)
    depth = (1.0 + rng.normal(0, 0.004, shape)).astype(np.float32)
    m = rect(shape, 10, 70, 10, 70)
    assert len(split_by_depth(m, depth)) == 1


def test_dedupe_removes_repeats_and_makes_masks_disjoint():
    a = rect((60, 60), 0, 40, 0, 40)
    a2 = rect((60, 60), 1, 40, 0, 39)           # a repeat of a
    b = rect((60, 60), 30, 60, 30, 60)          # overlaps a a little
    out = dedupe([a, a2, b], min_pixels=10)
    assert len(out) == 2
    assert not (out[0] & out[1]).any()


def test_label_image_round_trip_and_refine():
    a = rect((60, 60), 0, 30, 0, 30)
    b = rect((60, 60), 30, 60, 30, 60)
    lbl = to_label_image([a, b])
    assert lbl.dtype == np.uint16 and lbl[5, 5] == 1 and lbl[50, 50] == 2 and lbl[5, 50] == 0
    assert len(refine([a, b, rect((60, 60), 0, 2, 58, 60)], None, min_pixels=20)) == 2


def _dedupe_full_frame(masks, max_iou=0.5, min_pixels=200):
    """dedupe as it was written first (every overlap counted over the whole frame)."""
    from shelfpick.perception.masks import iou

    order = sorted(range(len(masks)), key=lambda i: -int(masks[i].sum()))
    kept, taken = [], None
    for i in order:
        m = masks[i].astype(bool)
        area = m.sum()
        if area < min_pixels:
            continue
        if any(iou(m, k) > max_iou or np.logical_and(m, k).sum() > max_iou * area for k in kept):
            continue
        if taken is not None:
            m = m & ~taken
            if m.sum() < min_pixels:
                continue
        kept.append(m)
        taken = m.copy() if taken is None else (taken | m)
    return kept


@pytest.mark.parametrize("seed", range(20))
def test_dedupe_counting_in_bounding_boxes_gives_the_full_frame_answer(seed):
    rng = np.random.default_rng(seed)
    masks = []
    for _ in range(int(rng.integers(2, 25))):
        m = np.zeros((60, 80), bool)
        y, x = rng.integers(0, 50), rng.integers(0, 70)
        m[y:y + rng.integers(1, 30), x:x + rng.integers(1, 40)] = True
        if rng.random() < 0.3:
            m &= rng.random(m.shape) < 0.8          # ragged masks too
        masks.append(m)
    for min_pixels in (0, 1, 30):
        want = _dedupe_full_frame(masks, 0.5, min_pixels)
        got = dedupe(masks, 0.5, min_pixels)
        assert len(got) == len(want) and all((g == w).all() for g, w in zip(got, want))
