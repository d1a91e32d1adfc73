"""Perceive's speed-ups of session 52 give the very numbers (bit for bit) of the plain numpy they
replaced: each is checked here against that plain form, on random inputs."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from shelfpick.perception import faces
from shelfpick.perception.face_gate import dominant_plane
from shelfpick.perception.geometry import _points, backproject, pixel_rays, pose_matrix, ray_plane
from shelfpick.perception.masks import fill_holes, to_label_image
from shelfpick.perception.overlay import _tinted, palette
from shelfpick.perception.pixels import label_masks, label_sums
from shelfpick.perception.scene import Camera

CAM = Camera(64, 48, 60.0, 61.0, 31.5, 23.5, 0.001, (0.02, -1.0, 0.6), (0.70, -0.71, 0.03, 0.01))


def _same(a: np.ndarray, b: np.ndarray) -> None:
    assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _blobs(rng: np.random.Generator, n: int = 7, shape: tuple[int, int] = (48, 64)) -> np.ndarray:
    labels = np.zeros(shape, np.uint16)
    for k in range(1, n + 1):
        y, x = rng.integers(0, shape[0] - 8), rng.integers(0, shape[1] - 8)
        labels[y:y + rng.integers(2, 20), x:x + rng.integers(2, 20)] = k
    return labels


@pytest.mark.parametrize("seed", range(5))
def test_label_sums_over_the_labelled_pixels_are_the_whole_frames_bincount(seed):
    rng = np.random.default_rng(seed)
    labels = _blobs(rng).astype(np.int32)
    lab = rng.random((48, 64, 3)).astype(np.float32)           # a channel of it: a strided view
    for values in (lab[..., 1], labels > 3, lab[..., 0] * lab[..., 2]):
        for idx in (np.arange(1, 5), np.arange(1, 12), np.array([6, 2])):
            want = np.bincount(labels.ravel(), weights=np.asarray(values).ravel(), minlength=idx.max() + 1)[idx]
            _same(label_sums(values, labels, idx), want)


def test_label_masks_are_the_label_comparisons():
    labels = _blobs(np.random.default_rng(1), 9)
    for n in (0, 4, 9, 12):                  # 12: labels asked for that are not there
        got = label_masks(labels, n)
        assert len(got) == n
        for k, m in enumerate(got, start=1):
            _same(m, labels == k)


def _flood_frame(mask: np.ndarray) -> np.ndarray:
    """fill_holes as it was: the whole frame flooded from its corner."""
    h, w = mask.shape
    flood = np.zeros((h + 2, w + 2), np.uint8)
    flood[1:-1, 1:-1] = mask.astype(np.uint8)
    cv2.floodFill(flood, np.zeros((h + 4, w + 4), np.uint8), (0, 0), 1)
    return mask.astype(bool) | (flood[1:-1, 1:-1] == 0)


@pytest.mark.parametrize("seed", range(20))
def test_holes_filled_in_the_masks_box_are_the_whole_frames(seed):
    rng = np.random.default_rng(seed)
    m = cv2.dilate((rng.random((48, 64)) < 0.05).astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
    m[:, :rng.integers(0, 3)] = False
    for mask in (m, m[10:30, 5:50], ~m, np.zeros((5, 5), bool), np.ones((5, 5), bool)):
        _same(fill_holes(mask), _flood_frame(mask))


def test_label_image_built_in_boxes_is_the_whole_frame_loop():
    rng = np.random.default_rng(4)
    masks = [label_masks(_blobs(rng, 3), 3)[k] for k in range(3)] + [rng.random((48, 64)) < 0.1]
    want = np.zeros((48, 64), np.uint16)
    for i, m in enumerate(masks, start=1):
        want[(want == 0) & m] = i
    _same(to_label_image(masks), want)


def test_rays_points_and_plane_hits_are_the_stacked_formulas():
    rng = np.random.default_rng(2)
    us, vs, z = rng.random(500) * 64, rng.random(500) * 48, rng.random(500) * 2
    rot, t = pose_matrix(CAM)
    rays = np.stack([(us - CAM.cx) / CAM.fx, (vs - CAM.cy) / CAM.fy, np.ones(500)], axis=-1)
    _same(pixel_rays(CAM, us, vs), rays)
    _same(backproject(CAM, us, vs, z), rays * z[..., None] @ rot.T + t)
    point, normal = np.array([0.1, 0.3, 0.4]), np.array([0.1, 0.99, 0.05])
    dirs = rays @ rot.T
    s = ((point - t) @ normal) / (dirs @ normal)
    _same(ray_plane(CAM, us, vs, point, normal), t + dirs * s[:, None])


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_a_frames_points_written_in_place_are_np_stacks(dtype):
    depth = (np.random.default_rng(3).random((48, 64)) * 2).astype(dtype)
    rot, t = (a.astype(np.float32) for a in pose_matrix(CAM))
    vs, us = np.arange(48)[:, None], np.arange(64)[None, :]
    x = ((us - CAM.cx) / CAM.fx).astype(np.float32) * depth
    y = ((vs - CAM.cy) / CAM.fy).astype(np.float32) * depth
    _same(_points(CAM, depth), np.stack([x, y, depth.astype(np.float32)], axis=-1) @ rot.T + t)


def test_the_overlays_tint_table_is_the_per_pixel_blend():
    rng = np.random.default_rng(5)
    rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    labels = _blobs(rng, 11)
    cols = palette(12)
    for alpha in (0.45, 0.0, 1.0, 0.3):
        want = rgb.copy()
        sel = labels > 0
        want[sel] = (want[sel] * (1 - alpha) + cols[labels[sel]] * alpha).astype(np.uint8)
        _same(_tinted(rgb, labels, cols, alpha), want)


def test_dominant_planes_distances_in_place_pick_the_draw_they_picked():
    rng = np.random.default_rng(6)
    pts = np.concatenate([rng.random((300, 3)) * [0.3, 0.004, 0.3], rng.random((100, 3))])
    for seed in range(5):
        s = pts[np.random.default_rng(seed).integers(0, len(pts), size=(50, 3))]
        n = np.cross(s[:, 1] - s[:, 0], s[:, 2] - s[:, 0])
        nn = np.linalg.norm(n, axis=1)
        ok = nn > 1e-12                         # (a draw of one point twice gives no plane)
        n, o = n[ok] / nn[ok, None], s[ok, 0]
        dist = np.abs(pts @ n.T - np.einsum("ij,ij->i", o, n))
        inl = dist[:, int(np.argmax((dist < 0.01).sum(axis=0)))] < 0.01
        c = pts[inl].mean(axis=0)
        want = np.linalg.svd(pts[inl] - c, full_matrices=False)[2][2]
        normal, share = dominant_plane(pts, 0.01, 50, np.random.default_rng(seed))
        _same(normal, want)
        assert share == float(inl.mean())


def test_a_face_measured_again_inside_a_call_is_measured_once_and_its_own_object(monkeypatch):
    depth = np.full((48, 64), 1.0, np.float32)
    mask = np.zeros((48, 64), bool)
    mask[10:30, 12:40] = True
    outside = faces.measure_front(mask, depth, CAM)
    calls = []
    measure = faces._measure
    monkeypatch.setattr(faces, "_measure", lambda *a: calls.append(1) or measure(*a))
    with faces.faces_cached():
        first, again = faces.measure_front(mask, depth, CAM), faces.measure_front(mask.copy(), depth.copy(), CAM)
        other = faces.measure_front(mask, depth * 1.1, CAM)
    assert len(calls) == 2                      # the mask on the other depth is measured
    assert first == again == outside and first is not again and other != first
    faces.measure_front(mask, depth, CAM)        # outside a call: measured, nothing remembered
    assert len(calls) == 3


def test_freed_pages_are_kept_where_malloc_is_glibcs_and_setting_it_again_is_harmless():
    import platform

    from shelfpick.perception.heap_pages import keep_freed_pages

    took = keep_freed_pages()
    assert took == (platform.system() == "Linux" and platform.libc_ver()[0] == "glibc")
    assert keep_freed_pages() == took
    assert np.array_equal(np.ones((600, 600)).sum(axis=0), np.full(600, 600.0))   # arrays as before


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_offsets_and_columnwise_are_numpys_broadcasts(dtype):
    from shelfpick.perception.geometry import columnwise, offsets

    rng = np.random.default_rng(7)
    pts, origin, per_row = (rng.random(s).astype(dtype) for s in ((300, 3), 3, 300))
    _same(offsets(pts, origin), pts - origin)
    _same(columnwise(pts.copy(), np.add, origin), pts + origin)
    _same(columnwise(pts.copy(), np.multiply, per_row, by_row=True), pts * per_row[:, None])


def test_the_networks_input_planes_are_the_broadcast_scaling():
    from shelfpick.perception.segment_learned import MEAN, STD, to_array

    rng = np.random.default_rng(8)
    for rgb in (rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), rng.random((9, 7, 3)) * 255):
        want = (np.ascontiguousarray(rgb, np.float32) - MEAN) / STD
        _same(to_array(rgb), np.ascontiguousarray(want.transpose(2, 0, 1))[None])
