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


# --- session 52, second helper: the print repairs, the depth rules' piece merges, the box sweep


def _sweep_per_axis(a, b, direction):
    """contact.sweep as it was: each axis's projections and their ends taken in the loop."""
    from shelfpick.perception.contact import _axes, box_corners

    d = np.asarray(direction, float)
    ca, cb = box_corners(a), box_corners(b)
    lo, hi = -np.inf, np.inf
    for n in _axes(a, b):
        pa, pb = ca @ n, cb @ n
        a0, a1, b0, b1 = pa.min(), pa.max(), pb.min(), pb.max()
        nd = float(n @ d)
        if abs(nd) < 1e-9:
            if a0 >= b1 - 1e-9 or b0 >= a1 - 1e-9:
                return None
            continue
        t0, t1 = sorted(((b0 - a1) / nd, (b1 - a0) / nd))
        lo, hi = max(lo, t0), min(hi, t1)
        if lo >= hi:
            return None
    return float(lo), float(hi)


def test_the_sweep_from_remembered_extents_is_the_per_axis_sweep():
    from shelfpick.perception.contact import _cross, pose_memo, sweep
    from shelfpick.perception.scene import Box

    rng = np.random.default_rng(9)
    for u, v in rng.normal(size=(50, 2, 3)):
        _same(_cross(u, v), np.cross(u, v))
    boxes = []
    for k in range(12):
        q = rng.normal(size=4) * [1, 0.1, 0.1, 0.3] if k % 3 else np.array([1.0, 0, 0, 0])
        boxes.append(Box(str(k), tuple(rng.uniform(0.1, 0.4, 3)), tuple(rng.uniform(-0.3, 0.3, 3)),
                         tuple(q / np.linalg.norm(q))))
    for d in ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.3, 0.0, 0.9)):
        want = [_sweep_per_axis(a, b, d) for a in boxes for b in boxes]
        assert [sweep(a, b, d) for a in boxes for b in boxes] == want          # outside a memo
        with pose_memo():
            assert [sweep(a, b, d) for a in boxes for b in boxes] == want
            assert [sweep(a, b, d) for a in boxes for b in boxes] == want      # remembered


def _profile_transposed(mask, lab, axis):
    """repeats.profile as it was: the strips' pixels read through the transposed image."""
    from shelfpick.perception.repairs.repeats import L_WEIGHT, STRIPS

    m = mask if axis == 0 else mask.T
    im = lab if axis == 0 else lab.transpose(1, 0, 2)
    width = m.sum(axis=1)
    idx = np.flatnonzero(width >= 0.5 * np.median(width[width > 0]))
    lo, hi = int(idx[0]), int(idx[-1]) + 1
    sub = m[lo:hi]
    first = np.argmax(sub, axis=1)
    span = np.maximum(sub.shape[1] - np.argmax(sub[:, ::-1], axis=1) - first, 1)
    rr, cc = np.nonzero(sub)
    key = rr * STRIPS + np.minimum((cc - first[rr]) * STRIPS // span[rr], STRIPS - 1)
    nb = (hi - lo) * STRIPS
    n = np.bincount(key, minlength=nb).reshape(hi - lo, STRIPS).astype(float)
    vals = im[lo:hi][rr, cc]
    tot = np.stack([np.bincount(key, weights=vals[:, k], minlength=nb) for k in range(3)], -1)
    out = np.where((n >= 2)[..., None], tot.reshape(hi - lo, STRIPS, 3) / np.maximum(n, 1)[..., None], np.nan)
    out[..., 0] *= L_WEIGHT
    flat = out.reshape(hi - lo, -1)
    for c in range(flat.shape[1]):
        col = flat[:, c]
        bad = np.isnan(col)
        if bad.all():
            flat[:, c] = 0.0
        elif bad.any():
            col[bad] = np.interp(np.flatnonzero(bad), np.flatnonzero(~bad), col[~bad])
    return lo, flat


def _alike_apart(prof, a, c, b):
    """repeats._alike_two as it was: each part resampled and its spread taken on its own."""
    from shelfpick.perception.repairs.repeats import MIN_SPREAD, SAMPLES

    n, t = len(prof), np.linspace(0.0, 1.0, SAMPLES)

    def gather(lo, hi):
        x = np.clip(lo[:, None] + (hi - 1 - lo)[:, None] * t, 0, n - 1)
        i = np.minimum(x.astype(int), max(n - 2, 0))
        w = (x - i)[..., None]
        return prof[i] * (1 - w) + prof[np.minimum(i + 1, n - 1)] * w

    p, q = gather(a, c), gather(c, b)
    sp = ((p - p.mean(1, keepdims=True)) ** 2).sum(2).mean(1)
    sq = ((q - q.mean(1, keepdims=True)) ** 2).sum(2).mean(1)
    out = 1 - ((p - q) ** 2).sum(2).mean(1) / np.maximum(sp + sq, 1e-9)
    return np.where(np.minimum(sp, sq) < MIN_SPREAD ** 2, -1.0, out)


@pytest.mark.parametrize("seed", range(4))
def test_the_print_profile_and_scores_are_the_transposed_and_per_part_ones(seed):
    from shelfpick.perception.repairs import repeats

    rng = np.random.default_rng(seed)
    lab = (rng.random((60, 70, 3)) * [100, 60, 60]).astype(np.float32)
    lab[:, :, 1] += np.sin(np.arange(70) / 3.0)[None, :].astype(np.float32) * 20     # a print to repeat
    mask = np.zeros((60, 70), bool)
    mask[5:55, 8:64] = True
    mask[rng.integers(0, 60, 300), rng.integers(0, 70, 300)] = False               # gaps in rows
    mask[5:12, 8:20] = False
    for axis in (0, 1):
        lo, prof = repeats.profile(mask, lab, axis)
        want_lo, want = _profile_transposed(mask, lab, axis)
        assert lo == want_lo
        _same(prof, want)
        n = len(prof)
        cs = np.arange(12, n - 11, 2, dtype=float)
        for kind in (0, 1, 2):
            win = repeats._windows(n, cs, kind)
            _same(repeats._alike_two(prof, *win), _alike_apart(prof, *win))
    px = lab[mask]
    assert repeats._spread(px) == pytest.approx(float((px * np.array([repeats.L_WEIGHT, 1.0, 1.0])).var(axis=0).sum()),
                                                rel=1e-12)


def test_the_best_coarse_cut_of_all_kinds_at_once_is_the_kind_by_kind_one():
    from shelfpick.perception.repairs.repeats import _coarse, _windows

    rng = np.random.default_rng(10)
    for n in (24, 40, 77):
        prof = np.repeat(rng.normal(0, 20, (n // 4 + 1, 9)), 4, axis=0)[:n] + rng.normal(0, 3, (n, 9))
        ranges = ((max(12, int(0.2 * n)), min(n - 12, int(0.8 * n))), (12, n // 2 - 1), (n - n // 2 + 1, n - 12))
        for step in (1, 3):
            best = (-1.0, 0, 0.0)
            for kind, (lo, hi) in enumerate(ranges):
                cs = np.arange(lo, hi + 1, step, dtype=float)
                if len(cs):
                    sc = _alike_apart(prof, *_windows(n, cs, kind))
                    j = int(np.argmax(sc))
                    if sc[j] > best[0]:
                        best = (float(sc[j]), kind, float(cs[j]))
            assert _coarse(prof, ranges, step) == best


def test_the_halves_dilations_touches_and_cover_in_boxes_are_the_whole_frames():
    from shelfpick.perception.repairs.halves import GAP_PX, _bbox, _cover, _near, _touch

    labels = _blobs(np.random.default_rng(11), 9)
    labels[0:5, 0:6] = 10                                     # at the image's corner
    masks = [labels == k for k in range(1, 11)] + [np.zeros(labels.shape, bool)]
    boxes = [_bbox(m) for m in masks]
    kernel = np.ones((2 * GAP_PX + 1, 2 * GAP_PX + 1), np.uint8)
    near = [_near(m, b) for m, b in zip(masks, boxes)]
    for m, nm in zip(masks, near):
        _same(nm, cv2.dilate(m.astype(np.uint8), kernel).astype(bool))
    for i in range(len(masks)):
        for j in range(len(masks)):
            assert _touch(near[i], masks[j], boxes[i], boxes[j]) == int((near[i] & masks[j]).sum())
    masks[2] = masks[2] | masks[3]                              # masks overlap: pixels claimed twice
    _same(_cover(masks, [_bbox(m) for m in masks]), np.sum(masks, axis=0, dtype=np.uint8))


def test_piece_colours_and_unions_in_boxes_are_label_sums_and_whole_frame_isin():
    from shelfpick.perception.piece_merge import _colours, _Unions, rect_fill

    rng = np.random.default_rng(12)
    labels = _blobs(rng, 9).astype(np.int32)
    labels[labels == 4] = 0                                   # a label that is not there
    core = rng.random(labels.shape) > 0.2
    lab = (rng.random((48, 64, 3)) * 255).astype(np.float32)
    n, idx = 9, np.arange(1, 10)
    src = np.where(core, labels, 0)
    cnt = np.maximum(np.bincount(src.ravel(), minlength=n + 1)[1:n + 1], 1)
    got_cnt, got_mean = _colours(labels, core, lab, n)
    _same(got_cnt, cnt)
    _same(got_mean, np.stack([label_sums(lab[..., c], src, idx) / cnt for c in range(3)], axis=1))
    unions = _Unions(labels, n)
    for ids in ([1], [2, 3], [4], [4, 7, 9], [5, 6, 8, 1]):
        part, win = unions(ids)
        _same(unions.full(part, win), np.isin(labels, ids))
        assert rect_fill(part) == rect_fill(np.isin(labels, ids))


def test_piece_borders_found_once_are_each_rules_own_comparisons():
    from shelfpick.perception.piece_merge import _borders, _thickness, contacts, seam_fraction
    from shelfpick.perception.pixels import label_percentiles

    rng = np.random.default_rng(13)
    labels = _blobs(rng, 12).astype(np.int32)
    edges = rng.random(labels.shape) > 0.6
    mpp = (rng.random(labels.shape) * 0.002).astype(np.float32)
    n, touch, tot, hit = 12, {}, {}, {}
    for a, b, ea, eb in ((labels[:, :-1], labels[:, 1:], edges[:, :-1], edges[:, 1:]),
                         (labels[:-1, :], labels[1:, :], edges[:-1, :], edges[1:, :])):
        for y, x in zip(*np.nonzero((a != b) & (a > 0) & (b > 0))):
            key = (int(min(a[y, x], b[y, x])), int(max(a[y, x], b[y, x])))
            touch[key] = touch.get(key, 0) + 1
            hit[key] = hit.get(key, 0) + int(ea[y, x] | eb[y, x])
    borders = _borders(labels)
    assert contacts(labels, borders) == touch
    assert seam_fraction(labels, edges, borders) == {k: hit[k] / v for k, v in touch.items() if v >= 10}
    border = ~(cv2.morphologyEx((labels > 0).astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0)
    for a, b, sl_a, sl_b in ((labels[:, 1:], labels[:, :-1], np.s_[:, 1:], np.s_[:, :-1]),
                             (labels[1:, :], labels[:-1, :], np.s_[1:, :], np.s_[:-1, :])):
        diff = (a != b) & (a > 0) & (b > 0)
        border[sl_a] |= diff
        border[sl_b] |= diff
    dist = cv2.distanceTransform((~border).astype(np.uint8), cv2.DIST_L2, 3)
    idx = np.arange(1, n + 1)
    _same(_thickness(labels, mpp, idx, borders), 2 * label_percentiles(dist * mpp, labels, idx, 90))
