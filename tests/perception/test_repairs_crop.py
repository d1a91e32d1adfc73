"""The repairs' crops to a mask's box give exactly the full frame's numbers (they exist only for speed)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from shelfpick.perception.catalogue import Catalogue
from shelfpick.perception.pixels import nonzero
from shelfpick.perception.repairs.crop import Near, box, box_nonzero
from shelfpick.perception.repairs.measure import RepairContext


def _blobs(seed: int, n: int = 40, shape: tuple[int, int] = (60, 80)) -> list[np.ndarray]:
    """Random masks: rectangles with holes and specks, some at the frame's edges, and an empty one."""
    rng = np.random.default_rng(seed)
    out = [np.zeros(shape, bool)]
    for _ in range(n):
        m = np.zeros(shape, bool)
        y0, x0 = rng.integers(-5, shape[0] - 3), rng.integers(-5, shape[1] - 3)
        m[max(0, y0):y0 + rng.integers(2, 30), max(0, x0):x0 + rng.integers(2, 40)] = True
        m &= rng.random(shape) < rng.uniform(0.6, 1.0)
        out.append(m)
    return out


@pytest.mark.parametrize("seed", [1, 2])
def test_box_holds_the_mask_and_box_nonzero_is_nonzero(seed):
    valid = np.random.default_rng(seed + 10).random((60, 80)) < 0.8
    for m in _blobs(seed):
        win = box(m)
        if not m.any():
            assert win is None
        else:
            assert m[win].sum() == m.sum()
        for also in (None, valid):
            want = nonzero(m if also is None else m & also)
            got = box_nonzero(m, also)
            for w, g in zip(want, got):
                assert g.dtype == w.dtype
                np.testing.assert_array_equal(g, w)


@pytest.mark.parametrize("gap", [1, 4, 12])
def test_near_is_the_full_frame_dilation(gap):
    kernel = np.ones((2 * gap + 1,) * 2, np.uint8)
    masks = _blobs(3)
    for m in masks:
        full = cv2.dilate(m.astype(np.uint8), kernel) > 0
        near = Near(m, kernel, gap)
        np.testing.assert_array_equal(near.full(), full)
        for o in masks:
            assert near.touches(o) == bool((full & o).any())


def test_the_opening_on_the_box_is_the_full_frames():
    """`stepped._on_pieces_plane` opens its mask's part on the mask's box (2 px round it): the
    same pixels as on the full frame. (Its chamfer distances stay on the full frame: on a crop
    they can differ in the last bit, which this test once showed.)"""
    rng = np.random.default_rng(5)
    k3 = np.ones((3, 3), np.uint8)
    for m in _blobs(4)[1:]:
        if not m.any():
            continue
        on = m & (rng.random(m.shape) < 0.7)
        win = box(m, 2)
        opened = cv2.morphologyEx(on.astype(np.uint8), cv2.MORPH_OPEN, k3) > 0
        cropped = np.zeros_like(m)
        cropped[win] = cv2.morphologyEx(on[win].astype(np.uint8), cv2.MORPH_OPEN, k3) > 0
        np.testing.assert_array_equal(cropped, opened)


def test_the_lab_table_is_the_arithmetic():
    rgb = np.random.default_rng(6).integers(0, 256, (30, 40, 3), dtype=np.uint8)
    want = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
    want[..., 1:] = (want[..., 1:] - 128) * 2
    got = RepairContext(np.ones((30, 40), np.float32), None, Catalogue(), rgb).lab  # type: ignore[arg-type]
    assert got.dtype == want.dtype and got.tobytes() == want.tobytes()


def test_plane_residuals_and_distances_on_the_box_are_the_full_frames():
    from synth_frames import box as scene_box, cast

    from shelfpick.perception.faces import measure_front
    from shelfpick.perception.repairs.measure import FaceCache, plane_dist
    from shelfpick.perception.repairs.planes import plane_res
    from shelfpick.perception.scene import Scene, Shelf

    cap = cast(Scene(Shelf(), (scene_box("a", -0.10, 0.0, 0.20, 0.20), scene_box("b", 0.15, 0.0, 0.23, 0.25))))
    a, b = cap.masks == 1, cap.masks == 2
    face = measure_front(a, cap.depth, cap.camera)
    plain, cached = (RepairContext(cap.depth, cap.camera, Catalogue(), None, c) for c in (None, FaceCache()))
    full = plane_res(face, b, plain)
    win = box(b, 2)
    np.testing.assert_array_equal(plane_res(face, b, plain, win), full[win])
    outside = np.ones(full.shape, bool)
    outside[win] = False
    assert np.isinf(full[outside]).all() and np.isfinite(full[b]).any()
    for m in (a, b):
        d = plane_dist(face, m, plain)
        assert plane_dist(face, m, cached) == d == plane_dist(face, m, cached)
