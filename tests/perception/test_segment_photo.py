"""The photo segmenter (no depth) on small carton photos drawn in code."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from shelfpick.perception.evaluation.bench import match
from shelfpick.perception.segment_photo import PhotoConfig, PhotoSegmenter, edge_map


def draw_stack(seed: int, rows: int = 3, cols: int = 3, similar: bool = False,
               size: tuple[int, int] = (360, 480)) -> tuple[np.ndarray, list[np.ndarray]]:
    """A photo of a stack of cartons: a wall and a floor behind, `rows` x `cols` carton faces
    (slightly skewed quadrilaterals) with dark seams between them, white labels with dark
    print and a tape band on some; returns the RGB image and one true mask per carton."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = np.zeros((h, w, 3), np.float32)
    wall = np.linspace(150, 200, h)[:, None, None] * np.array([0.9, 0.95, 1.0])
    img[:] = wall
    floor = int(h * 0.82)
    img[floor:] = (95, 100, 105)
    img += rng.normal(0, 3, img.shape)
    x0, y0 = 50, 40
    cw, ch = (w - 2 * x0) // cols, (floor - y0) // rows
    base = np.array([176, 134, 88], np.float32)          # cardboard brown
    truth = []
    for r in range(rows):
        for c in range(cols):
            tone = base if similar else base * rng.uniform(0.8, 1.15) + rng.uniform(-12, 12, 3)
            sk = rng.uniform(-3, 3, (4, 2))
            quad = np.array([[x0 + c * cw + 2, y0 + r * ch + 2], [x0 + (c + 1) * cw - 2, y0 + r * ch + 2],
                             [x0 + (c + 1) * cw - 2, y0 + (r + 1) * ch - 2], [x0 + c * cw + 2, y0 + (r + 1) * ch - 2]],
                            np.float64) + sk
            q = np.round(quad).astype(np.int32)
            m = np.zeros((h, w), np.uint8)
            cv2.fillPoly(m, [q], 1)
            face = m.astype(bool)
            img[face] = tone + rng.normal(0, 4, (int(face.sum()), 3))
            cv2.polylines(img, [q], True, (35, 30, 25), 2)   # the shadowed seam
            lx, ly = int(quad[0, 0] + rng.uniform(0.15, 0.5) * cw), int(quad[0, 1] + rng.uniform(0.2, 0.45) * ch)
            lw, lh = int(cw * 0.3), int(ch * 0.3)
            cv2.rectangle(img, (lx, ly), (lx + lw, ly + lh), (235, 235, 230), -1)   # label
            for k in range(3):
                cv2.line(img, (lx + 4, ly + 6 + 7 * k), (lx + lw - 6, ly + 6 + 7 * k), (40, 40, 40), 2)
            if rng.random() < 0.5:                           # printed logo
                cv2.circle(img, (int(quad[0, 0] + 0.2 * cw), int(quad[0, 1] + 0.75 * ch)), 8, (60, 40, 30), -1)
            truth.append(face)
    return np.clip(img, 0, 255).astype(np.uint8), truth


def draw_flush_grid(seed: int, rows: int = 4, cols: int = 5, seam: tuple[int, int, int] = (120, 100, 80),
                    tape: bool = True, size: tuple[int, int] = (480, 640)) -> tuple[np.ndarray, list[np.ndarray]]:
    """Cartons of one kind packed flush in rows and columns (a pallet seen from above or a
    full shelf): the same brown, 1 px faint seams, a tape band right across every face at the
    same height, a label on each."""
    rng = np.random.default_rng(seed)
    h, w = size
    img = np.full((h, w, 3), (120, 125, 130), np.float32) + rng.normal(0, 3, (h, w, 3))
    x0, y0 = 40, 30
    cw, ch = (w - 2 * x0) // cols, (h - 2 * y0) // rows
    base = np.array([186, 150, 105], np.float32)
    truth = []
    for r in range(rows):
        for c in range(cols):
            m = np.zeros((h, w), np.uint8)
            cv2.rectangle(m, (x0 + c * cw, y0 + r * ch), (x0 + (c + 1) * cw - 1, y0 + (r + 1) * ch - 1), 1, -1)
            face = m.astype(bool)
            img[face] = base * rng.uniform(0.95, 1.05) + rng.normal(0, 4, (int(face.sum()), 3))
            if tape:
                yy = y0 + r * ch + ch // 2
                cv2.rectangle(img, (x0 + c * cw, yy - 6), (x0 + (c + 1) * cw, yy + 6), (200, 175, 130), -1)
            lx, ly = x0 + c * cw + int(rng.uniform(0.1, 0.5) * cw), y0 + r * ch + int(rng.uniform(0.1, 0.25) * ch)
            cv2.rectangle(img, (lx, ly), (lx + cw // 4, ly + ch // 5), (240, 240, 235), -1)
            truth.append(face)
    for r in range(rows + 1):
        cv2.line(img, (x0, y0 + r * ch), (x0 + cols * cw, y0 + r * ch), seam, 1)
    for c in range(cols + 1):
        cv2.line(img, (x0 + c * cw, y0), (x0 + c * cw, y0 + rows * ch), seam, 1)
    img = cv2.GaussianBlur(img, (0, 0), 0.7)
    return np.clip(img, 0, 255).astype(np.uint8), truth


def _found(seed: int, **kw) -> tuple[int, int, list[float], int]:
    rgb, truth = draw_stack(seed, **kw)
    masks = PhotoSegmenter().segment(rgb, None)
    pairs = match(masks, truth, 0.5)
    return len(pairs), len(truth), [v for _, _, v in pairs], len(masks)


@pytest.mark.parametrize("seed", [0, 1])
def test_every_carton_of_a_drawn_stack_is_one_mask(seed):
    matched, n, ious, _ = _found(seed)
    assert matched == n, (matched, n)
    assert min(ious) > 0.8, ious      # labels and print inside a face belong to it


def test_cartons_of_one_colour_are_kept_apart_by_their_seams():
    matched, n, ious, _ = _found(3, similar=True, rows=2, cols=3)
    assert matched == n and min(ious) > 0.8, (matched, n, ious)


def test_flush_grids_of_one_kind_are_cut_along_their_faint_seams():
    """No colour step between the cartons, only 1 px seams; the tape bands line up across the
    whole grid but are no seam (a step of colour, not a dark line). Ten grids of 20: 192 of
    200 cartons found when this was written (one grid with tape lost 8); asserted >= 180."""
    found = total = 0
    ious = []
    for seed in range(5):
        for tape in (True, False):
            rgb, truth = draw_flush_grid(seed, tape=tape)
            pairs = match(PhotoSegmenter().segment(rgb, None), truth, 0.5)
            found += len(pairs)
            total += len(truth)
            ious += [v for _, _, v in pairs]
    assert total == 200 and found >= 180, found
    assert np.median(ious) > 0.85


def test_background_alone_gives_no_carton():
    rng = np.random.default_rng(0)
    h, w = 240, 320
    img = (np.linspace(140, 200, h)[:, None, None] * np.ones((1, w, 3)) + rng.normal(0, 3, (h, w, 3)))
    img[int(h * 0.8):] = 100
    masks = PhotoSegmenter().segment(np.clip(img, 0, 255).astype(np.uint8), None)
    assert masks == [], [int(m.sum()) for m in masks]


def test_masks_are_disjoint_full_size_and_the_same_for_the_same_image():
    rgb, _ = draw_stack(5, size=(720, 960))            # larger than the work size: scaled back
    a = PhotoSegmenter().segment(rgb, None)
    b = PhotoSegmenter().segment(rgb, np.ones(rgb.shape[:2], np.float32))   # depth is ignored
    assert a and all(m.shape == rgb.shape[:2] and m.dtype == bool for m in a)
    assert np.max(np.sum(a, axis=0)) == 1
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))


def test_edge_map_marks_a_dark_seam_and_not_a_plain_wall():
    rng = np.random.default_rng(1)
    img = np.full((120, 160, 3), 170.0) + rng.normal(0, 3, (120, 160, 3))
    img[:, 80:82] = 60                                    # a 2 px dark seam
    e = edge_map(np.clip(img, 0, 255).astype(np.uint8), PhotoConfig())
    assert e[:, 79:83].max(axis=1).min() > 0.8            # all along the seam
    assert np.percentile(e[:, :60], 99) < 0.15            # noise on the wall is no edge


def test_config_round_trips_through_json():
    cfg = PhotoConfig(levels=(0.2, 0.4), q0=0.6)
    assert PhotoConfig.from_json(cfg.to_json()) == cfg


def test_auto_uses_the_photo_segmenter_for_photos_and_depth_edges_for_rgbd():
    from shelfpick.perception.errors import PerceptionError
    from shelfpick.perception.segment import AutoSegmenter, for_capture, load_segmenter
    from shelfpick.perception.segment_depth import DepthEdgeSegmenter

    seg = AutoSegmenter("photo", rgbd="depth")      # RGB-D: the rules asked for (default: learned)
    assert isinstance(for_capture(seg, has_depth=False), PhotoSegmenter)
    assert isinstance(for_capture(seg, has_depth=True), DepthEdgeSegmenter)
    # asked for explicitly, the depth segmenter still runs on photos with its rgb_only settings
    photo_depth = for_capture(load_segmenter(None, "depth"), has_depth=False)
    assert isinstance(photo_depth, DepthEdgeSegmenter)
    assert photo_depth.config.rect_fill == DepthEdgeSegmenter().config.rgb_rect_fill
    assert isinstance(load_segmenter(None, "photo"), PhotoSegmenter)
    with pytest.raises(PerceptionError, match="photo"):
        load_segmenter("w.pt", "photo")
