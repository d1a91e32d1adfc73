"""perceive(): capture in, scene out; the errors users see."""
from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from perception.capture import Capture
from perception.errors import PerceptionError
from perception.pipeline import perceive
from perception.scene import Scene, Shelf
from perception.segment_depth import DepthEdgeSegmenter
from synth_frames import box, cast


def _scene():
    return Scene(Shelf(), (box("a", -0.30, 0, 0.30, 0.25), box("b", 0.0, 0, 0.25, 0.20, front=0.06),
                           box("c", 0.27, 0, 0.26, 0.30), box("d", -0.30, 0.25, 0.25, 0.20)))


def test_perceive_recovers_boxes_and_writes_consistent_labels():
    scene = _scene()
    cap = cast(scene, noise=0.001, tape=True)
    res = perceive(cap, DepthEdgeSegmenter(), scene.shelf)
    assert len(res.scene.boxes) == 4 and not res.warnings
    assert res.masks.dtype == np.uint16 and res.overlay.shape == cap.rgb.shape
    for b in res.scene.boxes:
        assert not b.depth_known
        m = res.masks == b.mask_label
        vals, counts = np.unique(cap.masks[m], return_counts=True)
        true = scene.box(cap.labels[int(vals[np.argmax(counts)])])
        assert np.linalg.norm(np.subtract(b.front_center, true.front_center)) < 0.015
        assert abs(b.size[0] - true.size[0]) < 0.015 and abs(b.size[2] - true.size[2]) < 0.015
    Scene.from_json(res.scene.to_json())  # a valid scene document


def test_no_boxes_gives_empty_scene_and_warning():
    cap = cast(Scene(Shelf(), ()))
    res = perceive(cap, DepthEdgeSegmenter())
    assert res.scene.boxes == () and any("no boxes" in w for w in res.warnings)


def test_intrinsics_outside_the_image_are_refused():
    cap = cast(_scene())
    bad = replace(cap.camera, cx=5000.0)
    with pytest.raises(PerceptionError, match="cx=5000"):
        perceive(Capture(cap.rgb, cap.depth, bad), DepthEdgeSegmenter())


def test_camera_of_wrong_size_and_all_zero_depth_are_refused():
    cap = cast(_scene())
    with pytest.raises(PerceptionError, match="camera is 640x480"):
        Capture(cap.rgb, cap.depth, replace(cap.camera, width=640, height=480))
    with pytest.raises(PerceptionError, match="no valid pixel"):
        Capture(cap.rgb, np.zeros_like(cap.depth), cap.camera)


def test_rgb_only_uses_a_planar_front():
    scene = _scene()
    cap = cast(scene)
    res = perceive(Capture(cap.rgb, None, cap.camera), DepthEdgeSegmenter(), front_distance=1.0)
    assert res.front_distance == 1.0 and len(res.scene.boxes) >= 3
    res2 = perceive(Capture(cap.rgb, None, cap.camera), DepthEdgeSegmenter(), box_size=(0.30, 0.25))
    assert res2.front_distance is not None and 0.7 < res2.front_distance < 1.4


def test_rendered_scenes_are_perceived_at_the_measured_accuracy():
    """Four rendered shelves (up to 10 boxes each, two structured, two unstructured; ~29 visible
    faces): the depth segmenter reached recall 0.97 and precision 0.93 on these at the time of
    writing; the asserts leave a margin of about two boxes."""
    pytest.importorskip("pybullet")
    from perception.bench import bench_rendered
    from perception.bench_scenes import sample_scene

    scenes = [(f"{k}-{i}", sample_scene(i, k, 10)) for i, k in
              enumerate(("structured", "unstructured", "structured", "unstructured"))]
    summary, frames = bench_rendered(scenes, 0, DepthEdgeSegmenter(), progress=False)
    s = summary["all"]
    assert s["true_boxes"] >= 25
    assert s["recall"] >= 0.90, s
    assert s["precision"] >= 0.85, s
    assert s["centre_err_median_m"] <= 0.01 and s["width_err_median_m"] <= 0.01, s
    assert s["height_err_median_m"] <= 0.01 and s["angle_err_median_deg"] <= 2.0, s
