"""`perception.pixels` gives exactly numpy's numbers (it exists only for speed)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy import ndimage

from shelfpick.perception.pixels import count, hull_candidates, label_percentiles, label_sums, nonzero


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


def _labels() -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(3)
    labels = rng.integers(0, 9, size=(40, 50))
    labels[labels == 4] = 0                               # a label not present: 0 / the default
    values = rng.random((40, 50)).astype(np.float32) * 3
    return labels, values


def test_label_sums_are_ndimage_sums():
    labels, values = _labels()
    idx = np.arange(1, 11)                                # 9 and 10 beyond the labels
    for v in (values, values.astype(np.float64), values > 1.5):
        got = label_sums(v, labels, idx)
        want = ndimage.sum(v, labels, idx)
        assert got.dtype == want.dtype
        np.testing.assert_array_equal(got, want)


def test_label_percentiles_are_the_labeled_comprehension_of_numpys_percentile():
    labels, values = _labels()
    for idx in (np.arange(1, 9), np.array([3, 1, 4, 8]), np.arange(0, 9)):
        for q in (90, 50, 10):
            want = ndimage.labeled_comprehension(values, labels, idx, lambda v: np.percentile(v, q), float, 0.0)
            got = label_percentiles(values, labels, idx, q)
            assert got.dtype == np.float64
            np.testing.assert_array_equal(got, want)


def test_depth_rules_finish_relabels_as_the_loop_it_replaced():
    """segment_depth._finish: labels 1..n of the faces big enough, in label order (it was a loop of
    np.unique's labels, one full-image comparison each)."""
    from shelfpick.perception.depth_edge_config import DepthEdgeConfig
    from shelfpick.perception.segment_depth import _finish

    labels, values = _labels()
    merged = labels * 3                                   # gaps between the labels
    mpp = values * 0.0015 * labels                      # label 1's face too small
    cfg = DepthEdgeConfig()
    want = np.zeros(merged.shape, np.uint16)
    k = 0
    for lbl in np.unique(merged)[1:]:
        if ndimage.sum(mpp * mpp, merged, [lbl])[0] < cfg.min_face_m2:
            continue
        k += 1
        want[merged == lbl] = k
    got = _finish(merged, mpp, cfg)
    assert got.dtype == want.dtype and k == 6            # of the 7 present, label 1 dropped
    np.testing.assert_array_equal(got, want)


def test_the_chroma_lookup_is_the_per_pixel_arithmetic():
    """segment_depth scales a Lab chroma channel through a 256-entry table: the same bytes as the
    float arithmetic it did on every pixel."""
    from shelfpick.perception.segment_depth import _chroma_lut

    ch = np.arange(256, dtype=np.uint8).reshape(16, 16)
    for gain in (2.5, 1.0, 0.3):
        want = np.clip((ch.astype(np.float32) - 128) * gain + 128, 0, 255).astype(np.uint8)
        np.testing.assert_array_equal(_chroma_lut(gain)[ch], want)


def _shapes(n: int, seed: int = 0) -> list[np.ndarray]:
    """Masks of ellipses, turned rectangles, lines and speckle, alone or together, 1-120 px a side."""
    rng = np.random.default_rng(seed)
    out = []
    while len(out) < n:
        h, w = (int(v) for v in rng.integers(1, 120, 2))
        m = np.zeros((h, w), np.uint8)
        for _ in range(int(rng.integers(1, 4))):
            c = (int(rng.integers(0, w)), int(rng.integers(0, h)))
            kind = int(rng.integers(0, 4))
            if kind == 0:
                cv2.ellipse(m, c, (int(rng.integers(0, 40)), int(rng.integers(0, 40))), float(rng.uniform(0, 180)),
                            0, 360, 1, -1)
            elif kind == 1:
                box = cv2.boxPoints((c, (float(rng.uniform(1, 60)), float(rng.uniform(1, 60))), float(rng.uniform(-90, 90))))
                cv2.fillPoly(m, [np.round(box).astype(np.int32)], 1)
            elif kind == 2:
                cv2.line(m, c, (int(rng.integers(0, w)), int(rng.integers(0, h))), 1, int(rng.integers(1, 4)))
            else:
                m |= (rng.random((h, w)) < 0.03).astype(np.uint8)
        if m.any():
            out.append(m.astype(bool))
    return out


def test_hull_candidates_give_the_min_area_rect_of_all_the_pixels():
    for m in _shapes(1500) + [np.ones((1, 1), bool), np.ones((1, 7), bool), np.ones((9, 1), bool)]:
        every = cv2.findNonZero(m.astype(np.uint8))
        some = hull_candidates(m)
        assert some.dtype == every.dtype and some.shape[1:] == (1, 2)
        flat = [p.reshape(-1, 2) @ [1, m.shape[1]] for p in (every, some)]
        assert np.isin(flat[1], flat[0]).all() and (np.diff(flat[1]) > 0).all()   # a row-major subsequence
        assert cv2.minAreaRect(some) == cv2.minAreaRect(every)
    assert hull_candidates(np.zeros((4, 5), bool)) is None


def test_the_faces_cross_product_is_numpys_to_the_bit():
    from shelfpick.perception.faces import _cross

    rng = np.random.default_rng(5)
    vectors = [rng.normal(size=3) for _ in range(300)] + [np.array([0.0, 1.0, 0.0]), np.array([-0.0, 0.0, -1.0]),
                                                          np.array([0.0, 0.0, 1.0])]
    for a in vectors:
        for b in (rng.normal(size=3), np.array([0.0, 0.0, 1.0]), a):
            want, got = np.cross(a, b), _cross(a, b)
            assert got.dtype == want.dtype and want.tobytes() == got.tobytes()   # signs of zeros too
