"""Mask clean-up: blobs, holes, depth splits, duplicates, label images."""
from __future__ import annotations

import numpy as np

from perception.masks import clean_mask, dedupe, fill_holes, refine, split_by_depth, to_label_image


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
