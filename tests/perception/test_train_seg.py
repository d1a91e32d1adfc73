"""Synthetic training data for the segmenter and a tiny real training run."""
from __future__ import annotations

import itertools

import numpy as np
import pytest

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.render import render
from shelfpick.perception.training.yolo import build_dataset, jittered_camera, sample_scene, train, yolo_label_lines


def _overlap(a, b, tol=0.004):
    ca, cb = np.array(a.corners()), np.array(b.corners())
    return all(min(ca[:, i].max(), cb[:, i].max()) - max(ca[:, i].min(), cb[:, i].min()) > tol for i in range(3))


@pytest.mark.parametrize("kind", ["structured", "unstructured"])
def test_sampled_shelves_are_plausible_and_seeded(kind):
    for seed in range(6):
        scene = sample_scene(np.random.default_rng(seed), kind)
        again = sample_scene(np.random.default_rng(seed), kind)
        assert scene == again
        assert len(scene.boxes) >= 1
        scene.check_bounds("sampled")
        for b in scene.boxes:   # every box stands on the floor or on the box below it
            bottom = min(c[2] for c in b.corners())
            tops = [o.top_z for o in scene.boxes if o is not b]
            assert abs(bottom) < 0.01 or any(abs(bottom - t) < 0.01 for t in tops), (seed, b)
        for a, b in itertools.combinations(scene.boxes, 2):
            if kind == "structured":
                assert not _overlap(a, b), (seed, a.id, b.id)


def test_label_lines_are_normalised_polygons_one_per_box():
    rng = np.random.default_rng(3)
    scene = sample_scene(rng, "structured")
    cap = render(scene, jittered_camera(rng), seed=3)
    lines = yolo_label_lines(cap.masks, cap.labels)
    big = [k for k in cap.labels if (cap.masks == k).sum() >= 40]
    assert len(lines) == len(big) > 0
    for ln in lines:
        vals = ln.split()
        assert vals[0] == "0" and len(vals) >= 7 and len(vals) % 2 == 1
        xy = np.array(vals[1:], float)
        assert ((xy >= 0) & (xy <= 1)).all()


def test_dataset_is_reused_not_rerendered(tmp_path):
    info = build_dataset(tmp_path, 3, seed=1, progress=False)
    assert (info.n_train, info.n_val) == (2, 1)
    img = tmp_path / "images" / "train" / "00001.png"
    stamp = img.stat().st_mtime_ns
    again = build_dataset(tmp_path, 3, seed=1, progress=False)
    assert img.stat().st_mtime_ns == stamp and again.n_instances == info.n_instances
    assert "names:" in info.yaml.read_text()


def test_tiny_training_run_gives_loadable_weights(tmp_path):
    from shelfpick.perception.segment_yolo import YoloSegmenter

    out = tmp_path / "tiny.pt"
    res = train(out, images=6, epochs=1, imgsz=128, batch=4, seed=0, progress=False)
    assert out.is_file() and out.stat().st_size > 1_000_000
    assert res.epochs == 1 and not res.resumed
    seg = YoloSegmenter(out, imgsz=128, conf=0.01)
    cap = render(sample_scene(np.random.default_rng(9), "structured"), seed=9)
    masks = seg.segment(cap.rgb, cap.depth)
    assert all(m.shape == cap.rgb.shape[:2] and m.dtype == bool for m in masks)
    # a finished run is not trained again: same weights back at once
    res2 = train(out, images=6, epochs=1, imgsz=128, batch=4, seed=0, progress=False)
    assert not res2.resumed and res2.epochs == 1


def test_bad_arguments_are_user_errors(tmp_path):
    with pytest.raises(PerceptionError, match="must end in .pt"):
        train(tmp_path / "weights.bin", images=2, epochs=1)
    with pytest.raises(PerceptionError, match="epochs"):
        train(tmp_path / "w.pt", images=2, epochs=0)
    from shelfpick.console.cli import main
    assert main(["train-seg", "--out", str(tmp_path / "w.txt")]) == 2


@pytest.mark.slow
def test_interrupted_training_resumes(tmp_path):
    """Stop after epoch 1 of 2, then the same call resumes from last.pt and finishes."""
    from ultralytics.models.yolo.segment import SegmentationTrainer

    out = tmp_path / "r.pt"
    orig = SegmentationTrainer.save_model

    def save_then_stop(self):
        orig(self)
        if self.epoch == 0:
            raise KeyboardInterrupt

    SegmentationTrainer.save_model = save_then_stop
    try:
        with pytest.raises(KeyboardInterrupt):
            train(out, images=5, epochs=2, imgsz=96, batch=4, progress=False)
    finally:
        SegmentationTrainer.save_model = orig
    res = train(out, images=5, epochs=2, imgsz=96, batch=4, progress=False)
    assert res.resumed and res.epochs == 2 and out.is_file()
