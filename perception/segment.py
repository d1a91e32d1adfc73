"""Choosing a segmenter: learned or depth-and-edge for RGB-D, YOLO11n-seg or the photo segmenter when asked for.

A segmenter is anything with `segment(rgb, depth) -> list[HxW bool mask]`
(one mask per box front face). `load_segmenter` picks one:
- `kind="yolo"` or explicit `weights`: YOLO11n-seg through ultralytics
  (`perception/segment_yolo.py`, the `train` extra); weights that do not load are a PerceptionError;
- `kind="depth"`: the depth-and-edge segmenter, no learned weights (on a photo: its
  `rgb_only()` settings over a flat stand-in depth);
- `kind="learned"`: `perception/segment_learned.py` on `weights` or the shipped
  `static/weights/shelfpick-learned.onnx` (ONNX Runtime; a `.pt` checkpoint runs on torch);
- `kind="photo"`: the photo segmenter (`perception/segment_photo.py`: edge map, candidate
  regions, carton-shaped ones kept), no learned weights, depth ignored;
- `kind="auto"` (default): the given weights when there are some; otherwise the
  segmenter that measured best for the kind of capture (`AutoSegmenter`): for RGB-D
  `RGBD` (the learned segmenter where its weights and onnxruntime are installed, else
  depth-and-edge; docs/perception.md "Learned segmenter"), for photos without depth
  `RGB_ONLY` (the learned segmenter too since its second training round, on the same
  fallback; docs/perception.md "Second training round").
`for_capture(seg, has_depth)` is what the pipeline calls to settle the choice.
"""
from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from shelfpick.perception.errors import PerceptionError

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_WEIGHTS = ROOT / "static" / "weights" / "shelfpick-seg.pt"
KINDS = ("auto", "depth", "photo", "yolo", "learned")


@runtime_checkable
class Segmenter(Protocol):
    def segment(self, rgb: np.ndarray, depth: np.ndarray | None) -> list[np.ndarray]: ...


# which segmenter `auto` uses for photos without depth: "learned" (segment_learned.LearnedSegmenter,
# not snapped or gated on a photo; the rules where its weights or onnxruntime are missing, as for RGB-D),
# "photo" (segment_photo.PhotoSegmenter), "depth" (the depth-and-edge segmenter on a flat
# stand-in depth) or "yolo" (the shipped weights). "learned" since the second training round
# (issue 14, docs/perception.md "Second training round: photo-like walls"): on the RCAN tune
# half, where the choice is made, recall 0.500 vs the rules' 0.338 (precision 0.366 vs 0.258);
# held out it also leads (RCAN 0.519 / 0.471 vs 0.403 / 0.397, telexistence 0.400 / 0.348 vs
# 0.125 / 0.357); with the photo inference settings (`LearnedConfig.for_photo`, docs/perception.md
# "Photo inference settings") RCAN held out 0.558 / 0.597, telexistence 0.525 / 0.429.
# Before: "depth" (the photo segmenter and the first learned weights were worse held out,
# docs/perception-photos.md); tests/perception/test_segment_learned.py asserts "learned".
RGB_ONLY = "learned"

# which segmenter `auto` uses for RGB-D captures: "learned" (segment_learned.LearnedSegmenter,
# where its weights and onnxruntime are installed; the rules otherwise) or "depth"
# (segment_depth.DepthEdgeSegmenter). "learned" since issue 14 (docs/perception.md "Learned
# segmenter"): with its depth gate and split it beats the rules on the held-out renders
# (1000-1049 1.000 / 1.000 vs 0.994 / 0.994, varied 0.976 / 0.988 vs 0.906 / 0.978) and the
# neura pallet (1.000 / 0.923 vs 0.833 / 0.769), and ties on the planning shelves (0.985 /
# 0.992 vs 0.988 / 0.988); tests/perception/test_segment_learned.py asserts "learned".
RGBD = "learned"


class AutoSegmenter:
    """`RGBD` for RGB-D captures, `RGB_ONLY` for photos (settled by `choose`). Holds the learned
    network once loaded, so a console that perceives frame after frame loads it once."""

    name = "auto"

    def __init__(self, rgb_only: str = RGB_ONLY, rgbd: str = RGBD, learned_weights: str | Path | None = None,
                 photo_weights: str | Path | None = None):
        """`learned_weights`: the learned network for RGB-D (default the shipped `.onnx`); `photo_weights`:
        for photos (default `learned_weights` when given, else the shipped photo network)."""
        self.rgb_only_kind = rgb_only
        self.rgbd_kind = rgbd
        self.learned_weights = Path(learned_weights) if learned_weights is not None else None
        given = photo_weights if photo_weights is not None else learned_weights
        self.photo_weights = Path(given) if given is not None else None
        self._nets: dict[Path, Segmenter] = {}    # learned segmenters by weights file, each loaded once

    def _weights(self, photo: bool) -> Path:
        """The weights file for photos or for RGB-D captures: the one given, else the shipped one."""
        from shelfpick.perception.segment_learned import LEARNED_ONNX, LEARNED_PHOTO_ONNX

        given = self.photo_weights if photo else self.learned_weights
        return given if given is not None else (LEARNED_PHOTO_ONNX if photo else LEARNED_ONNX)

    def _learned_or_rules(self, weights: Path) -> Segmenter:
        """The learned segmenter on `weights` (loaded once, shared by both kinds of capture when
        they name one file), or the rules where the file or its runtime is missing."""
        from shelfpick.perception.segment_depth import DepthEdgeSegmenter

        if not _usable(weights):
            return DepthEdgeSegmenter()
        if weights not in self._nets:
            self._nets[weights] = load_segmenter(weights, "learned")
        return self._nets[weights]

    def choose(self, has_depth: bool) -> Segmenter:
        from shelfpick.perception.segment_depth import DepthEdgeSegmenter

        if has_depth:
            if self.rgbd_kind != "learned":
                return DepthEdgeSegmenter()
            return self._learned_or_rules(self._weights(photo=False))
        if self.rgb_only_kind == "learned":
            return self._learned_or_rules(self._weights(photo=True))   # for_capture then takes its rgb_only() copy
        if self.rgb_only_kind == "photo":
            from shelfpick.perception.segment_photo import PhotoSegmenter

            return PhotoSegmenter()
        if self.rgb_only_kind == "depth" or not DEFAULT_WEIGHTS.is_file():
            return DepthEdgeSegmenter()
        return load_segmenter(DEFAULT_WEIGHTS, "yolo")

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None) -> list[np.ndarray]:
        # a photo asked of `auto` directly is read as the pipeline reads it (`for_capture`)
        return for_capture(self, depth is not None).segment(rgb, depth)


def _usable(weights: Path) -> bool:
    """A learned segmenter's weights file is there and its runtime is installed (onnxruntime for the
    shipped `.onnx`, in the `perception` extra; torch for a `.pt`)."""
    runtime = "onnxruntime" if weights.suffix.lower() == ".onnx" else "torch"
    return weights.is_file() and importlib.util.find_spec(runtime) is not None


def for_capture(seg: Segmenter, has_depth: bool) -> Segmenter:
    """The segmenter to run on a capture with or without a depth image."""
    choose = getattr(seg, "choose", None)
    if callable(choose):
        seg = choose(has_depth)
    if not has_depth and callable(getattr(seg, "rgb_only", None)):
        seg = seg.rgb_only()  # type: ignore[union-attr]
    return seg


def load_segmenter(weights: str | Path | None = None, kind: str = "auto") -> Segmenter:
    """The segmenter for `kind`; see the module docstring for the rules."""
    if kind not in KINDS:
        raise PerceptionError(f"unknown segmenter {kind!r}; choose one of {', '.join(KINDS)}")
    if kind == "learned":   # EfficientNet-Lite0 + decoder (perception/segment_learned.py)
        from shelfpick.perception.segment_learned import LEARNED_ONNX, LearnedSegmenter

        return LearnedSegmenter(weights if weights is not None else LEARNED_ONNX)
    if kind in ("depth", "photo"):
        if weights is not None:
            raise PerceptionError(f"--weights is for the yolo segmenter, not {kind!r}")
        if kind == "photo":
            from shelfpick.perception.segment_photo import PhotoSegmenter

            return PhotoSegmenter()
        from shelfpick.perception.segment_depth import DepthEdgeSegmenter

        return DepthEdgeSegmenter()
    if weights is None and kind == "auto":
        return AutoSegmenter()
    path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise PerceptionError(f"{path}: segmentation weights not found")
    from shelfpick.perception.segment_yolo import YoloSegmenter

    return YoloSegmenter(str(path))


def segmenter_name(seg: object) -> str:
    return str(getattr(seg, "name", type(seg).__name__))
