"""YOLO11n-seg box segmentation through ultralytics, strictly offline.

The method segments box front faces with YOLO11n-seg. Ultralytics likes to
reach the network (settings sync, a font download during training and
plotting, weight downloads for unknown names); a warehouse PC often has no
internet, so `offline_env()` pins it down before ultralytics is imported:
YOLO_OFFLINE, no auto-install, quiet logs and a project settings folder that
already holds the font it would download (a copy of matplotlib's DejaVuSans).
"""
from __future__ import annotations

import importlib.util
import os
import shutil
from pathlib import Path

import cv2
import numpy as np

from shelfpick.perception.errors import PerceptionError

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG_DIR = ROOT / ".yolo"
DEFAULT_IMGSZ = 320
DEFAULT_CONF = 0.10   # chosen on held-out renders for the shipped (short-trained) weights


def offline_env() -> Path:
    """Set ultralytics' offline environment (values already set are kept); returns its config dir.

    Must run before the first `import ultralytics` (it reads the variables at import).
    """
    os.environ.setdefault("YOLO_OFFLINE", "1")
    os.environ.setdefault("YOLO_AUTOINSTALL", "0")
    os.environ.setdefault("YOLO_VERBOSE", "0")
    if "YOLO_CONFIG_DIR" not in os.environ:
        cfg = DEFAULT_CONFIG_DIR
        try:
            cfg.mkdir(parents=True, exist_ok=True)
        except OSError:
            cfg = Path.home() / ".cache" / "shelfpick" / "yolo"
        os.environ["YOLO_CONFIG_DIR"] = str(cfg)
    cfg = Path(os.environ["YOLO_CONFIG_DIR"]).expanduser()
    fonts = cfg / "Ultralytics"
    try:
        fonts.mkdir(parents=True, exist_ok=True)
        missing = [n for n in ("Arial.ttf", "Arial.Unicode.ttf") if not (fonts / n).is_file()]
        if missing:
            import matplotlib

            src = Path(matplotlib.get_data_path()) / "fonts" / "ttf" / "DejaVuSans.ttf"
            for name in missing:
                tmp = fonts / (name + ".tmp")
                shutil.copyfile(src, tmp)
                tmp.replace(fonts / name)
    except OSError:
        pass  # read-only settings dir: inference never needs the font, only training plots do
    return cfg


def _load_yolo(weights: Path):
    if importlib.util.find_spec("ultralytics") is None:
        raise PerceptionError("the yolo segmenter needs ultralytics, which is not installed here: "
                              "pip install 'shelfpick[train]'")
    offline_env()
    if not weights.is_file():
        raise PerceptionError(f"{weights}: segmentation weights not found")
    try:
        from ultralytics import YOLO

        model = YOLO(str(weights), task="segment")
    except Exception as exc:  # noqa: BLE001 - any failure to load is the file's fault
        msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise PerceptionError(f"{weights}: cannot load YOLO segmentation weights ({msg})") from None
    if getattr(model, "task", "segment") != "segment":
        raise PerceptionError(f"{weights}: weights are for task {model.task!r}, expected 'segment'")
    return model


class YoloSegmenter:
    """Box front-face masks from a YOLO11n-seg model (one class, 'box')."""

    name = "yolo11n-seg"

    def __init__(self, weights: str | Path, imgsz: int = DEFAULT_IMGSZ, conf: float = DEFAULT_CONF,
                 iou: float = 0.6, max_det: int = 100):
        self.weights = Path(weights)
        self.imgsz = int(imgsz)
        self.conf = float(conf)
        self.iou = float(iou)
        self.max_det = int(max_det)
        self.model = _load_yolo(self.weights)
        self.last_scores: list[float] = []

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> list[np.ndarray]:
        """Bool HxW masks at the image's full resolution, most confident first.

        Depth is not used by the network (the method segments colour); it is
        part of the Segmenter signature so segmenters are interchangeable.
        """
        if rgb.ndim != 3 or rgb.shape[2] != 3:
            raise PerceptionError(f"RGB image must be HxWx3, got shape {rgb.shape}")
        h, w = rgb.shape[:2]
        bgr = np.ascontiguousarray(rgb[:, :, ::-1])  # ultralytics takes numpy images as BGR
        res = self.model.predict(bgr, imgsz=self.imgsz, conf=self.conf, iou=self.iou,
                                 max_det=self.max_det, retina_masks=True, verbose=False,
                                 device="cpu")[0]
        if res.masks is None or len(res.masks) == 0:
            self.last_scores = []
            return []
        data = res.masks.data.cpu().numpy() > 0.5
        scores = res.boxes.conf.cpu().numpy()
        if data.shape[1:] != (h, w):  # retina masks are full size; be safe on odd sizes
            data = np.stack([cv2.resize(m.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
                             for m in data])
        order = np.argsort(-scores)
        masks = [data[i] for i in order if data[i].any()]
        self.last_scores = [float(scores[i]) for i in order if data[i].any()]
        return masks


__all__ = ["YoloSegmenter", "offline_env", "DEFAULT_IMGSZ", "DEFAULT_CONF"]
