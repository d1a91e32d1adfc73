"""The RealSense recording path end to end: rendered frames recorded through a pyrealsense2
software device, played back through `bag:FILE` (console source) and perceived. Skips where
pyrealsense2 is not installed (it is the optional extra `shelfpick[realsense]`)."""
from __future__ import annotations

import numpy as np
import pytest

rs = pytest.importorskip("pyrealsense2")


def test_recorded_render_plays_back_and_is_perceived(tmp_path):
    from shelfpick.console.sources import open_source
    from shelfpick.perception.evaluation.bench import match
    from shelfpick.perception.evaluation.scenes import sample_scene
    from shelfpick.perception.evaluation.truth import front_face_masks
    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.realsense_record import record
    from shelfpick.perception.render import default_camera, render

    scene = sample_scene(1, "structured")
    cap = render(scene, default_camera(), seed=1)
    path = record(tmp_path / "shelf.db3", [cap, cap])
    default_camera().save(tmp_path / "camera.json")
    src = open_source(f"bag:{path}?camera={tmp_path / 'camera.json'}")
    try:
        got = src.capture().capture
    finally:
        src.close()
    assert np.array_equal(got.rgb, cap.rgb)
    v = cap.depth > 0
    close = np.abs(got.depth - cap.depth)[v] < 0.002
    assert close.mean() > 0.9                                  # align-to-colour leaves edge holes
    assert got.camera.position == default_camera().position   # the pose from the camera file
    truth = [m for m in front_face_masks(scene, cap).values() if m.sum() >= 400]
    res = perceive(got, None, scene.shelf)
    pairs = match([res.masks == b.mask_label for b in res.scene.boxes], truth)
    assert len(pairs) >= 0.8 * len(truth), (len(pairs), len(truth))
