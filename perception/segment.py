"""Choosing a segmenter: YOLO11n-seg weights when there are some, else depth and edges.

A segmenter is anything with `segment(rgb, depth) -> list[HxW bool mask]`
(one mask per box front face). `load_segmenter` picks one:
- `kind="yolo"` or explicit `weights`: YOLO11n-seg through ultralytics
  (`perception/segment_yolo.py`); weights that do not load are a PerceptionError;
- `kind="depth"`: the depth-and-edge segmenter, no learned weights;
- `kind="auto"` (default): the given weights, else the shipped
  `static/weights/shelfpick-seg.pt` when present, else depth-and-edge.
"""
from __future__ import annotations

from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from perception.errors import PerceptionError

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_WEIGHTS = ROOT / "static" / "weights" / "shelfpick-seg.pt"
KINDS = ("auto", "depth", "yolo")


@runtime_checkable
class Segmenter(Protocol):
    def segment(self, rgb: np.ndarray, depth: np.ndarray | None) -> list[np.ndarray]: ...


def load_segmenter(weights: str | Path | None = None, kind: str = "auto") -> Segmenter:
    """The segmenter for `kind`; see the module docstring for the rules."""
    if kind not in KINDS:
        raise PerceptionError(f"unknown segmenter {kind!r}; choose one of {', '.join(KINDS)}")
    if kind == "depth":
        if weights is not None:
            raise PerceptionError("--weights is for the yolo segmenter, not 'depth'")
        from perception.segment_depth import DepthEdgeSegmenter

        return DepthEdgeSegmenter()
    if weights is None and kind == "auto" and not DEFAULT_WEIGHTS.is_file():
        from perception.segment_depth import DepthEdgeSegmenter

        return DepthEdgeSegmenter()
    path = Path(weights) if weights is not None else DEFAULT_WEIGHTS
    if not path.is_file():
        raise PerceptionError(f"{path}: segmentation weights not found")
    from perception.segment_yolo import YoloSegmenter

    return YoloSegmenter(str(path))


def segmenter_name(seg: object) -> str:
    return str(getattr(seg, "name", type(seg).__name__))
