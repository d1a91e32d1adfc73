"""Capture sources: rendered demo shelves with their truth, folders of files, RealSense errors."""
from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

import shelfpick.console.sources as sources
from shelfpick.console.sources import SourceError, builtin_scene, open_source
from shelfpick.perception.capture import Capture
from shelfpick.perception.errors import ShelfpickError
from shelfpick.perception.scene import Box, Camera, Scene, Shelf


def test_demo_falls_back_to_the_builtin_shelf_and_cycles_looks(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(sources, "DEMO_DIR", tmp_path / "nothing-here")
    src = open_source("demo", seed=5)
    a, b = src.capture(), src.capture()
    assert a.truth == builtin_scene() and b.truth == builtin_scene()
    assert a.name == "demo:builtin#0" and b.name == "demo:builtin#1"
    assert a.capture.rgb.shape == (480, 640, 3) and a.capture.depth is not None
    assert set(a.capture.labels.values()) == set(builtin_scene().ids)  # every box's front face is visible
    assert not np.array_equal(a.capture.rgb, b.capture.rgb)  # a new look (seed) per capture
    again = open_source("demo", seed=5).capture()
    assert np.array_equal(again.capture.rgb, a.capture.rgb)  # same seed, same capture


def test_demo_cycles_through_shelf_files_and_picks_one(tmp_path: Path, monkeypatch) -> None:
    one = Scene(Shelf(), (Box("a", (0.2, 0.2, 0.2), (0.0, 0.11, 0.1)),))
    two = Scene(Shelf(), (Box("c", (0.2, 0.2, 0.2), (0.2, 0.11, 0.1)), Box("d", (0.2, 0.2, 0.2), (-0.2, 0.11, 0.1))))
    one.save(tmp_path / "one.json")
    two.save(tmp_path / "two.json")
    monkeypatch.setattr(sources, "DEMO_DIR", tmp_path)
    src = open_source("demo")
    assert [label for label, _ in src.scenes] == ["one", "two"]
    f = open_source("demo:two").capture()
    assert f.truth == two and f.name == "demo:two#0" and set(f.capture.labels.values()) == {"c", "d"}
    with pytest.raises(SourceError, match=r"demo:three: no demo shelf 'three'.*have: one, two"):
        open_source("demo:three")


def synthetic_capture() -> Capture:
    rng = np.random.default_rng(0)
    cam = Camera(32, 24, 30.0, 30.0, 16.0, 12.0)
    return Capture(rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), np.full((24, 32), 1.2, np.float32), cam)


def test_files_source_reads_the_folder_each_time(tmp_path: Path) -> None:
    cap = synthetic_capture()
    cap.save(tmp_path)
    src = open_source(f"files:{tmp_path}")
    f = src.capture()
    assert f.truth is None and np.array_equal(f.capture.rgb, cap.rgb)
    assert np.allclose(f.capture.depth, 1.2)
    truth = Scene(Shelf(), (Box("t", (0.2, 0.2, 0.2), (0.0, 0.11, 0.1)),))
    truth.save(tmp_path / "truth.json")
    (tmp_path / "rgb.png").unlink()
    cap2 = Capture(255 - cap.rgb, cap.depth, cap.camera)
    cap2.save(tmp_path)
    f2 = src.capture()
    assert f2.truth == truth and np.array_equal(f2.capture.rgb, cap2.rgb)
    (tmp_path / "camera.json").unlink()
    with pytest.raises(SourceError, match=r"camera\.json: missing"):
        src.capture()
    with pytest.raises(SourceError, match="capture folder not found"):
        open_source(f"files:{tmp_path / 'nope'}")


def test_a_broken_image_is_a_clear_error(tmp_path: Path) -> None:
    synthetic_capture().save(tmp_path)
    (tmp_path / "rgb.png").write_bytes(b"not a png")
    with pytest.raises(ShelfpickError, match=r"rgb\.png: not a readable image"):
        open_source(f"files:{tmp_path}").capture()


def test_realsense_and_bad_specs(tmp_path: Path) -> None:
    src = open_source("realsense")
    with pytest.raises(ShelfpickError) as err:
        src.capture()  # no pyrealsense2 here, or no camera connected
    msg = str(err.value)
    if importlib.util.find_spec("pyrealsense2") is None:
        assert "pyrealsense2" in msg
    else:
        assert "RealSense" in msg
    with pytest.raises(SourceError, match=r"missing\.bag: RealSense recording not found"):
        open_source(f"bag:{tmp_path / 'missing.bag'}")
    with pytest.raises(SourceError, match="expected demo, demo:NAME, files:DIR, realsense or bag:FILE"):
        open_source("webcam")
    with pytest.raises(SourceError, match="unknown option 'fps'"):
        open_source("realsense?fps=30")
