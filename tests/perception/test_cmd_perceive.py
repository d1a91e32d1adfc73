"""`shelfpick perceive` and `perceive-bench` end to end, and the RealSense error paths."""
from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from shelfpick.console.cli import main
from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.scene import Scene, Shelf
from synth_frames import box, cast


@pytest.fixture()
def capture_dir(tmp_path):
    scene = Scene(Shelf(), (box("a", -0.25, 0, 0.30, 0.25), box("b", 0.15, 0, 0.25, 0.20, front=0.06)))
    cast(scene, noise=0.001).save(tmp_path / "cap")
    return tmp_path / "cap"


def test_perceive_writes_scene_overlay_and_masks(capture_dir, tmp_path, capsys):
    out = tmp_path / "scene.json"
    rc = main(["perceive", "--rgb", str(capture_dir / "rgb.png"), "--depth", str(capture_dir / "depth.png"),
               "--camera", str(capture_dir / "camera.json"), "--segmenter", "depth", "--out", str(out),
               "--overlay", str(tmp_path / "ov.png"), "--masks", str(tmp_path / "m.png")])
    assert rc == 0
    scene = Scene.load(out)
    assert len(scene.boxes) == 2 and not scene.depth_known
    masks = cv2.imread(str(tmp_path / "m.png"), cv2.IMREAD_UNCHANGED)
    assert masks.dtype == np.uint16
    assert sorted(int(k) for k in np.unique(masks) if k) == sorted(b.mask_label for b in scene.boxes)
    assert cv2.imread(str(tmp_path / "ov.png")).shape == (240, 320, 3)


def test_perceive_bad_inputs_exit_2_with_one_line(capture_dir, tmp_path, capsys):
    cam = json.loads((capture_dir / "camera.json").read_text())
    cam["width"] = 640
    (tmp_path / "bad.json").write_text(json.dumps(cam))
    rc = main(["perceive", "--rgb", str(capture_dir / "rgb.png"), "--camera", str(tmp_path / "bad.json"),
               "--out", str(tmp_path / "s.json"), "--segmenter", "depth"])
    err = capsys.readouterr().err
    assert rc == 2 and "camera is 640x240" in err and len(err.strip().splitlines()) == 1
    rc = main(["perceive", "--rgb", str(tmp_path / "missing.png"), "--camera", str(capture_dir / "camera.json"),
               "--out", str(tmp_path / "s.json")])
    assert rc == 2 and "not found" in capsys.readouterr().err
    rc = main(["perceive", "--rgb", str(capture_dir / "rgb.png"), "--camera", str(capture_dir / "camera.json"),
               "--out", str(tmp_path / "s.json"), "--weights", str(tmp_path / "nope.pt")])
    assert rc == 2 and "nope.pt" in capsys.readouterr().err


def photo_only(capture_dir, tmp_path):
    """The capture's colour image and camera without its depth image: a photo."""
    import shutil

    photo = tmp_path / "photo"
    photo.mkdir()
    for name in ("rgb.png", "camera.json"):
        shutil.copy(capture_dir / name, photo / name)
    return photo


def test_perceive_without_depth_warns_and_uses_front_distance(capture_dir, tmp_path, capsys):
    photo = photo_only(capture_dir, tmp_path)
    rc = main(["perceive", "--rgb", str(photo / "rgb.png"), "--camera", str(photo / "camera.json"),
               "--out", str(tmp_path / "s.json"), "--segmenter", "photo"])
    assert rc == 0 and "no depth image" in capsys.readouterr().err
    assert len(Scene.load(tmp_path / "s.json").boxes) == 2


def test_perceive_refuses_a_shelf_sized_box_from_colour_alone(capture_dir, tmp_path, capsys):
    """Issue 13: the depth-and-edge segmenter on a flat stand-in depth took the shelf's back for one
    box (1.01 x 0.73 m) and wrote it with exit 0; now: exit 2, one line naming --depth, no file."""
    photo = photo_only(capture_dir, tmp_path)
    rc = main(["perceive", "--rgb", str(photo / "rgb.png"), "--camera", str(photo / "camera.json"),
               "--out", str(tmp_path / "s.json"), "--segmenter", "depth"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "--depth" in err[0] and "the size of the shelf" in err[0]
    assert not (tmp_path / "s.json").exists()


def test_perceive_refuses_an_rgbd_capture_without_its_depth(capture_dir, tmp_path, capsys):
    """The issue's case: a render's rgb.png perceived without --depth though depth.png lies beside it."""
    argv = ["perceive", "--rgb", str(capture_dir / "rgb.png"), "--camera", str(capture_dir / "camera.json"),
            "--out", str(tmp_path / "s.json"), "--segmenter", "photo"]
    rc = main(argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and f"--depth {capture_dir / 'depth.png'}" in err[0]
    assert not (tmp_path / "s.json").exists()
    assert main(argv + ["--front-distance", "1.0"]) == 0      # the colour alone, asked for


def test_perceive_bench_on_two_rendered_scenes(tmp_path, capsys):
    pytest.importorskip("pybullet")
    rc = main(["perceive-bench", "--count", "2", "--seed", "3", "--no-real", "--segmenter", "depth",
               "--out", str(tmp_path / "pb")])
    assert rc == 0
    rep = json.loads((tmp_path / "pb" / "report.json").read_text())
    assert rep["rendered"]["all"]["frames"] == 2 and rep["rendered"]["all"]["true_boxes"] > 0
    assert 0.0 <= rep["rendered"]["all"]["recall"] <= 1.0
    assert "Rendered scenes" in (tmp_path / "pb" / "report.md").read_text()


def test_realsense_errors_are_clear_without_the_library_or_a_camera(tmp_path):
    from shelfpick.perception import realsense

    try:
        import pyrealsense2  # noqa: F401
    except ImportError:
        with pytest.raises(PerceptionError, match="pip install 'shelfpick\\[realsense\\]'"):
            realsense.capture_live(timeout_ms=200)
        with pytest.raises(PerceptionError, match="pyrealsense2"):
            realsense.capture_bag(tmp_path / "x.bag")
    else:
        with pytest.raises(PerceptionError):
            realsense.capture_live(timeout_ms=200)
        with pytest.raises(PerceptionError, match="not found"):
            realsense.capture_bag(tmp_path / "x.bag")


def test_the_heap_setting_is_the_processs_owners_not_perceives(capture_dir, tmp_path, monkeypatch):
    """glibc's malloc kept for reuse (`heap_pages`) is a process-wide setting never undone: the CLI
    sets it at its start, `perceive()` itself does not (a library call changes no process-wide
    setting behind its caller's back)."""
    import shelfpick.perception.heap_pages as heap
    from shelfpick.perception.capture import load_capture
    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.segment import load_segmenter

    import shelfpick.perception.pipeline as pipeline

    calls: list[int] = []
    keep = lambda: calls.append(1) or True          # noqa: E731
    monkeypatch.setattr(heap, "keep_freed_pages", keep)
    monkeypatch.setattr(pipeline, "keep_freed_pages", keep, raising=False)   # a name imported there
    cap = load_capture(capture_dir / "rgb.png", capture_dir / "depth.png", capture_dir / "camera.json")
    perceive(cap, load_segmenter(None, "depth"))
    assert calls == []
    rc = main(["perceive", "--rgb", str(capture_dir / "rgb.png"), "--depth", str(capture_dir / "depth.png"),
               "--camera", str(capture_dir / "camera.json"), "--segmenter", "depth", "--out", str(tmp_path / "s.json")])
    assert rc == 0 and calls == [1]
