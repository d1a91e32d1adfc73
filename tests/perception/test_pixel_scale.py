"""Pixel thresholds that follow the distance (masks.pixel_scale): a camera set further back to
see a whole stack must join and cut faces like the default camera at ~1 m does."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.evaluation import bench
from shelfpick.perception.evaluation.scenes import sample_scene
from shelfpick.perception.box_catalogue import Catalogue
from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.masks import REF_DEPTH, pixel_scale, scaled_px
from shelfpick.perception.pipeline import _min_pixels
from shelfpick.perception.render import default_camera
from shelfpick.perception.segment_depth import DepthEdgeConfig, DepthEdgeSegmenter, _scaled


def test_pixel_scale_is_one_up_to_the_tuning_distance_and_shrinks_beyond() -> None:
    d = np.full((40, 60), 1.1, np.float32)
    assert pixel_scale(d) == 1.0
    assert pixel_scale(None) == 1.0
    far = np.full((40, 60), 2.0, np.float32)
    far[:5] = 0.0                                   # holes do not count
    assert pixel_scale(far) == pytest.approx(REF_DEPTH / 2.0)
    where = np.zeros_like(far, bool)
    where[20:, :] = True
    far[20:, :] = 3.0                               # only the pixels asked about
    assert pixel_scale(far, where) == pytest.approx(REF_DEPTH / 3.0)
    assert pixel_scale(np.full((4, 4), 50.0, np.float32)) == 0.3   # clamped
    assert pixel_scale(np.zeros((4, 4), np.float32)) == 1.0       # no valid depth
    assert scaled_px(12, 0.6) == 7 and scaled_px(2, 0.1, least=2) == 2


def test_catalogue_and_segmenter_thresholds_scale() -> None:
    cat = Catalogue()
    assert cat.scaled(1.0) is cat
    c2 = cat.scaled(0.5)
    assert (c2.max_join_gap_px, c2.l_margin_px) == (6, 5)
    assert c2.faces == cat.faces and c2.tol == cat.tol            # metric settings untouched
    cfg = DepthEdgeConfig()
    near = np.full((30, 30), 1.0, np.float32)
    fg = np.ones((30, 30), bool)
    assert _scaled(cfg, near, fg) is cfg
    far = _scaled(cfg, np.full((30, 30), 2.4, np.float32), fg)
    assert far.line_min == round(cfg.line_min / 2) and far.line_extend == cfg.line_extend
    photo = DepthEdgeSegmenter().rgb_only().config           # no depth: the distance is a guess
    assert _scaled(photo, np.full((30, 30), 2.4, np.float32), fg) is photo
    assert _min_pixels((480, 640), 0.5) == 40 and _min_pixels((480, 640)) == 150


def test_bench_camera_at_distance() -> None:
    base = default_camera()
    c = bench.camera_at(1.05)
    assert np.allclose(c.position, base.position) and np.allclose(c.orientation, base.orientation, atol=1e-9)
    far = bench.camera_at(1.6)
    assert far.position[1] == pytest.approx(-1.6) and far.fx == base.fx
    assert bench.min_gt_pixels(far) < bench.MIN_GT_PIXELS == bench.min_gt_pixels(c)
    with pytest.raises(PerceptionError, match="distance"):
        bench.camera_at(9.0)


def test_perceived_from_1_6_m_like_from_1_05_m() -> None:
    """Seed 206 (structured, 7 faces): from 1.6 m with ~1 m pixel thresholds three faces came
    back in pieces (10 boxes, 6 matched); with the thresholds scaled every face is found once."""
    sc = sample_scene(206, "structured", 10)
    fr = bench.eval_rendered(sc, "structured-206", 206, None, bench.camera_at(1.6))
    assert fr.n_true == 7
    assert (fr.matched, fr.n_pred) == (7, 7)
    near = bench.eval_rendered(sc, "structured-206", 206, None, bench.camera_at(1.05))
    assert near.matched == near.n_true and near.n_pred == near.n_true
