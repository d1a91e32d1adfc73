"""Train the YOLO11n-seg box segmenter on synthetic renders, offline, resumably.

No pretrained weights can be downloaded where this runs, so the model is
built from `yolo11n-seg.yaml` and trained from scratch on shelves rendered by
`perception.render`: random structured (neat columns) and unstructured
(mixed sizes, turned, set back) shelves of the method's box types, seen from
a jittered D435 pose. Polygons come from the ground-truth instance masks.

Layout of a work folder (everything is re-used when a run is repeated):
  dataset/images/{train,val}/NNNNN.png, dataset/labels/{train,val}/NNNNN.txt,
  dataset/data.yaml, run/weights/{last,best}.pt (ultralytics).
Rendering skips images already written (each image has its own seed), and
training resumes from run/weights/last.pt when it is there and unfinished.
"""
from __future__ import annotations

import csv
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.geometry import matrix_to_quat
from shelfpick.perception.render import default_camera, render
from shelfpick.perception.scene import BOX_TYPES as scene_box_types
from shelfpick.perception.scene import Box, Camera, Scene, Shelf, yaw_quat
from shelfpick.perception.segment_yolo import offline_env

# The method's box types (cm, as listed): each may stand on any face that fits the shelf depth.
BOX_TYPES: tuple[tuple[float, float, float], ...] = tuple(scene_box_types.values())
SHELF = Shelf()     # the method's shelf (1.0 x 0.30 x 1.60 m): scene.Shelf's defaults, its one definition
VIEW_TOP = 1.15    # nothing above this is in view from the default camera; stop stacking there


def _orientations(size: tuple[float, float, float], max_depth: float) -> list[tuple[float, float, float]]:
    """Distinct (width, depth, height) permutations whose depth fits the shelf."""
    a, b, c = size
    perms = {(a, b, c), (a, c, b), (b, a, c), (b, c, a), (c, a, b), (c, b, a)}
    return sorted(p for p in perms if p[1] <= max_depth)


def sample_scene(rng: np.random.Generator, kind: str = "unstructured", shelf: Shelf = SHELF) -> Scene:
    """A random shelf for training images: boxes resting on the floor or on each other.

    Rendering needs no physics, only plausible geometry, so boxes are placed
    column by column on a height map (no overlaps, nothing floating).
    """
    boxes: list[Box] = []
    x = -shelf.width / 2 + float(rng.uniform(0.0, 0.05))
    structured = kind == "structured"
    while True:
        t = BOX_TYPES[rng.integers(len(BOX_TYPES))]
        w, d, h = _orientations(t, shelf.depth)[rng.integers(len(_orientations(t, shelf.depth)))]
        if x + w > shelf.width / 2 - 0.005:
            break
        if rng.random() < (0.08 if structured else 0.18):   # an empty slot
            x += w + float(rng.uniform(0.0, 0.05))
            continue
        n = int(rng.integers(1, 5))
        gap = float(rng.uniform(0.0, 0.015 if structured else 0.05))   # to the next column
        z = 0.0
        col_w = w
        front = float(rng.uniform(0.0, 0.02)) if structured else float(rng.uniform(-0.02, shelf.depth - d))
        for k in range(n):
            if k > 0 and not structured and rng.random() < 0.5:   # a different box on top
                t2 = BOX_TYPES[rng.integers(len(BOX_TYPES))]
                opts = [o for o in _orientations(t2, shelf.depth) if o[0] <= col_w + 0.06]
                if not opts:
                    break
                w2, d2, h2 = opts[rng.integers(len(opts))]
            else:
                w2, d2, h2 = w, d, h
            if z + h2 > min(shelf.height, VIEW_TOP):
                break
            yaw = 0.0 if structured else float(rng.normal(0, math.radians(5)))
            if abs(yaw) > 0:   # keep a turned box inside its column
                yaw = float(np.clip(yaw, -math.radians(12), math.radians(12)))
            # structured boxes stay inside their column and its gap: no two boxes overlap
            dx = float(rng.uniform(0.0, gap)) if structured else float(rng.uniform(-0.03, 0.03))
            cx = float(np.clip(x + col_w / 2 + dx, -shelf.width / 2 + w2 / 2 + 0.005, shelf.width / 2 - w2 / 2 - 0.005))
            fy = front if (structured or k == 0) else float(np.clip(front + rng.uniform(-0.03, 0.05), -0.02, shelf.depth - d2))
            boxes.append(Box(f"b{len(boxes)}", (w2, d2, h2), (cx, fy + d2 / 2, z + h2 / 2), yaw_quat(yaw)))
            z += h2
        x += col_w + gap
    return Scene(shelf, tuple(boxes))


def jittered_camera(rng: np.random.Generator) -> Camera:
    """The default D435 pose moved a little, as a mount or a hand-held capture would."""
    base = default_camera()
    pitch = math.radians(90 + rng.uniform(14, 26))
    yaw = math.radians(rng.uniform(-4, 4))
    roll = math.radians(rng.uniform(-2, 2))

    def rx(a):
        return np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])

    def rz(a):
        return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])

    r = rz(yaw) @ rx(-pitch) @ rz(roll)   # world yaw, tilt, then roll about the optical axis
    pos = (float(rng.uniform(-0.08, 0.08)), float(rng.uniform(-1.12, -0.98)), float(rng.uniform(0.70, 0.90)))
    return Camera(base.width, base.height, base.fx, base.fy, base.cx, base.cy, base.depth_scale,
                  pos, matrix_to_quat(r))


def mask_polygon(mask: np.ndarray, min_area: float = 40.0) -> np.ndarray | None:
    """Outline of the largest blob of a bool mask, (N,2) pixel coordinates, or None if tiny."""
    contours, _ = cv2.findContours(mask.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
    if not contours:
        return None
    c = max(contours, key=cv2.contourArea)
    if cv2.contourArea(c) < min_area:
        return None
    c = cv2.approxPolyDP(c, 0.7, True)
    if len(c) < 3:
        return None
    return c.reshape(-1, 2).astype(np.float64)


def yolo_label_lines(masks: np.ndarray, labels) -> list[str]:
    """One `0 x1 y1 x2 y2 ...` line (normalised polygon) per visible box."""
    h, w = masks.shape
    lines = []
    for label in sorted(labels):
        poly = mask_polygon(masks == label)
        if poly is None:
            continue
        poly[:, 0] = np.clip(poly[:, 0] / w, 0, 1)
        poly[:, 1] = np.clip(poly[:, 1] / h, 0, 1)
        lines.append("0 " + " ".join(f"{v:.5f}" for v in poly.reshape(-1)))
    return lines


@dataclass(frozen=True)
class DatasetInfo:
    root: Path
    yaml: Path
    n_train: int
    n_val: int
    n_instances: int


def build_dataset(root: str | Path, images: int, seed: int = 0, val_fraction: float = 0.15,
                  progress: bool = True) -> DatasetInfo:
    """Render `images` random shelves into a YOLO-seg dataset (skips files already there)."""
    root = Path(root)
    n_val = max(1, int(round(images * val_fraction))) if images > 1 else 0
    instances = 0
    for i in tqdm(range(images), desc="rendering", unit="img", disable=not progress):
        split = "val" if i < n_val else "train"
        img_p = root / "images" / split / f"{i:05d}.png"
        lbl_p = root / "labels" / split / f"{i:05d}.txt"
        if img_p.is_file() and lbl_p.is_file():
            instances += sum(1 for ln in lbl_p.read_text().splitlines() if ln.strip())
            continue
        rng = np.random.default_rng([seed, i])
        scene = sample_scene(rng, "structured" if rng.random() < 0.4 else "unstructured")
        cap = render(scene, jittered_camera(rng), seed=int(rng.integers(2**31)), noise=True)
        lines = yolo_label_lines(cap.masks, cap.labels)
        img_p.parent.mkdir(parents=True, exist_ok=True)
        lbl_p.parent.mkdir(parents=True, exist_ok=True)
        cv2.imwrite(str(img_p), cap.rgb[:, :, ::-1])
        tmp = lbl_p.with_suffix(".tmp")
        tmp.write_text("\n".join(lines) + ("\n" if lines else ""))
        tmp.replace(lbl_p)
        instances += len(lines)
    if n_val == 0:   # one image: validate on the training image
        (root / "images" / "val").mkdir(parents=True, exist_ok=True)
        (root / "labels" / "val").mkdir(parents=True, exist_ok=True)
        for sub in ("images", "labels"):
            for f in (root / sub / "train").iterdir():
                shutil.copyfile(f, root / sub / "val" / f.name)
    yaml = root / "data.yaml"
    yaml.write_text(f"path: {root.resolve()}\ntrain: images/train\nval: images/val\nnames:\n  0: box\n")
    return DatasetInfo(root, yaml, images - n_val, max(n_val, 1), instances)


@dataclass(frozen=True)
class TrainResult:
    weights: Path
    epochs: int
    map50_95: float | None     # validation mask mAP50-95 of the best epoch
    map50: float | None        # validation mask mAP50
    dataset: DatasetInfo
    resumed: bool


def _finished(ckpt_path: Path) -> bool:
    import torch   # heavy and optional: only when training

    ckpt = torch.load(ckpt_path, map_location="cpu", weights_only=False)
    return ckpt.get("epoch", -1) == -1


def _best_metrics(run_dir: Path) -> tuple[float | None, float | None, int]:
    """(mask mAP50-95, mask mAP50, epochs done) of the best epoch from ultralytics' results.csv."""
    path = run_dir / "results.csv"
    if not path.is_file():
        return None, None, 0
    with path.open() as fh:
        rows = [{k.strip(): v for k, v in r.items()} for r in csv.DictReader(fh)]
    if not rows:
        return None, None, 0
    key, key50 = "metrics/mAP50-95(M)", "metrics/mAP50(M)"
    best = max(rows, key=lambda r: 0.1 * float(r.get(key50, 0) or 0) + 0.9 * float(r.get(key, 0) or 0))
    return float(best[key]), float(best[key50]), len(rows)


def train(out: str | Path, images: int = 300, epochs: int = 30, imgsz: int = 320, seed: int = 0,
          batch: int = 16, work: str | Path | None = None, workers: int = 0,
          progress: bool = True, val_every_epoch: bool = False) -> TrainResult:
    """Render a dataset, train YOLO11n-seg from scratch on the CPU, copy the best weights to `out`.

    Validation runs after the last epoch only unless `val_every_epoch`: on a
    barely trained model it is slower than the epoch itself (hundreds of
    candidate masks per image), and on two CPU cores that time is training.
    """
    out = Path(out)
    if out.suffix != ".pt":
        raise PerceptionError(f"{out}: the output weights file must end in .pt")
    if images < 1 or epochs < 1 or imgsz < 32:
        raise PerceptionError(f"need images >= 1, epochs >= 1, imgsz >= 32; got {images}, {epochs}, {imgsz}")
    # absolute: ultralytics puts a relative `project` under its own runs/<task>/ folder
    work = (Path(work) if work is not None else out.with_name(out.stem + ".work")).resolve()
    offline_env()
    data = build_dataset(work / "dataset", images, seed, progress=progress)
    run_dir = work / "run"
    last = run_dir / "weights" / "last.pt"
    model, resumed = _model_to_train(last)
    if model is not None:
        _fit(model, resumed, progress, epochs, dict(
            data=str(data.yaml), epochs=epochs, imgsz=imgsz, batch=batch, device="cpu",
            workers=workers, project=str(work), name="run", exist_ok=True, seed=seed,
            deterministic=True, pretrained=False, amp=False, plots=False, verbose=False,
            patience=max(10, epochs), cache="ram", close_mosaic=max(1, epochs // 5),
            val=val_every_epoch, warmup_epochs=min(3.0, max(0.5, epochs / 10))))
    best = run_dir / "weights" / "best.pt"
    if not best.is_file():
        best = last
    if not best.is_file():
        raise PerceptionError(f"{run_dir}: training produced no weights")
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".pt.tmp")
    shutil.copyfile(best, tmp)
    tmp.replace(out)
    m, m50, done = _best_metrics(run_dir)
    return TrainResult(out, done, m, m50, data, resumed)


def _model_to_train(last: Path):
    """(YOLO model or None when `last` finished training already, resumed?): a fresh
    YOLO11n-seg, or the unfinished run in `last` to resume."""
    from ultralytics import YOLO   # after offline_env(); heavy and optional: only when training

    if last.is_file() and not _finished(last):
        return YOLO(str(last)), True
    if last.is_file():
        return None, False   # already trained to the end
    return YOLO("yolo11n-seg.yaml"), False


def _fit(model, resumed: bool, progress: bool, epochs: int, settings: dict) -> None:
    """Train `model` (resume, or from scratch with ultralytics `settings`) with a progress bar
    of epochs and mask mAP50."""
    bar = tqdm(total=epochs, desc="training", unit="epoch", disable=not progress)

    def on_epoch(trainer) -> None:
        bar.n = min(trainer.epoch + 1, bar.total)
        m = trainer.metrics or {}
        bar.set_postfix(mask_mAP50=f"{m.get('metrics/mAP50(M)', 0):.3f}")
        bar.refresh()

    model.add_callback("on_fit_epoch_end", on_epoch)
    try:
        if resumed:
            model.train(resume=True)
        else:
            model.train(**settings)
    finally:
        bar.close()


__all__ = ["sample_scene", "jittered_camera", "build_dataset", "train", "TrainResult", "BOX_TYPES",
           "yolo_label_lines", "mask_polygon"]
