"""benchmarks/generators: independent frames of a tiny shelf built in code: seeded, exact depth where
the look says so, ground truth that names the boxes, and files `load_capture` reads."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest
from bench_scripts import ROOT

if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.generators import make_frame, write_frame  # noqa: E402

SCENE = {"format": "shelfpick.scene/1", "shelf": {"width": 1.0, "depth": 0.3, "height": 1.6},
         "boxes": [{"id": "a", "size": [0.31, 0.25, 0.23], "position": [-0.2, 0.125, 0.115],
                    "orientation": [1, 0, 0, 0]},
                   {"id": "b", "size": [0.2, 0.2, 0.2], "position": [0.15, 0.05, 0.1],
                    "orientation": [1, 0, 0, 0]},
                   {"id": "c", "size": [0.31, 0.25, 0.23], "position": [-0.2, 0.125, 0.345],
                    "orientation": [1, 0, 0, 0]}]}


def _front_z(frame, box: dict) -> float:
    """Camera z of the centre of a box's front face (what the depth image holds there)."""
    fc = np.array(box["position"]) - np.array([0, box["size"][1] / 2, 0])
    return float((fc - np.array(frame.cam.pos)) @ np.array(frame.cam.rot)[:, 2])


@pytest.mark.parametrize("look", ["flat", "printed", "stereo"])
def test_each_look_is_seeded_and_its_truth_names_every_box(look: str) -> None:
    f1, f2 = make_frame(SCENE, look, 0, "t"), make_frame(SCENE, look, 0, "t")
    other = make_frame(SCENE, look, 1, "t")
    assert np.array_equal(f1.rgb, f2.rgb) and np.array_equal(f1.depth, f2.depth)
    assert not np.array_equal(f1.rgb, other.rgb)
    assert f1.rgb.shape == (480, 640, 3) and f1.depth.shape == (480, 640)
    assert set(f1.labels.values()) == {"a", "b", "c"}
    for label, box_id in f1.labels.items():
        m = f1.masks == label
        assert m.sum() > 500, box_id
        ys, xs = np.nonzero(m)
        cy, cx = int(np.median(ys)), int(np.median(xs))
        box = next(b for b in SCENE["boxes"] if b["id"] == box_id)
        valid = f1.depth[m] > 0
        tol = 0.005 if look != "stereo" else 0.03
        assert abs(float(np.median(f1.depth[m][valid])) - _front_z(f1, box)) < 0.15 + tol   # roughly its face
        if look != "stereo":
            assert f1.depth[cy, cx] > 0


def test_flat_depth_is_exact_at_a_front_face_centre() -> None:
    f = make_frame(SCENE, "flat", 0, "t")
    box = SCENE["boxes"][1]
    fc = np.array(box["position"]) - np.array([0, box["size"][1] / 2, 0])
    (u, v), = f.cam.project(fc[None])
    assert f.masks[int(round(v)), int(round(u))] == 2
    assert abs(float(f.depth[int(round(v)), int(round(u))]) - _front_z(f, box)) < 0.004


def test_stereo_depth_has_holes_the_flat_one_does_not() -> None:
    flat, stereo = make_frame(SCENE, "flat", 0, "t"), make_frame(SCENE, "stereo", 0, "t")
    assert (flat.depth == 0).mean() < 0.001
    assert (stereo.depth == 0).mean() > 0.01


def test_written_files_load_as_a_capture(tmp_path) -> None:
    from shelfpick.perception.capture import load_capture

    p = write_frame(SCENE, "printed", 3, tmp_path / "f", "t")
    cap = load_capture(p["rgb"], p["depth"], p["camera"])
    assert cap.shape == (480, 640) and cap.camera.width == 640
    assert json.loads(p["masks_json"].read_text()) == {"1": "a", "2": "b", "3": "c"}
    assert json.loads(p["meta"].read_text()) == {"look": "printed", "seed": 3, "scene": "t"}
