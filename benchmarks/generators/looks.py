"""Four looks of a ray-cast shelf (issue 31): `flat`, `printed`, `stereo`, `labels`.

- flat: flat untextured shading, cartons of nearly one kraft colour, a camera-side light, only
  weak seams where faces end; exact depth with 0.7 mm of noise.
- printed: strong directional light from the upper left with hard shadows; every carton printed
  with ONE design (white board, a blue band, a red logo, text rows), so neighbours look alike.
- stereo: soft light, a wider range of carton colours, sensor noise, blur and vignetting; depth as
  a 5.5 cm-baseline stereo camera gives it: holes where the second camera cannot see, disparity
  quantised to 1/16 px (error grows with z^2), flying pixels at depth edges, dropout patches.
- labels (a TUNING look, added by h19 for printed cartons): every carton of a frame printed with ONE
  design drawn per frame from a family (kraft or white board; 0-2 coloured bands across or down
  the face; a logo block; rows of dark stencil text; a white shipping label with a bar code),
  a strong directional light from a direction drawn per frame (left or right, high or low) with
  hard shadows of drawn strength; drawn focal length and camera height.

Each `make_*` takes a shelfpick.scene/1 dict and a numpy Generator and returns a `Frame`. Which
looks train, tune and are held out is fixed in docs/perception.md, section "Roles".
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from benchmarks.generators.raycast import Cam, blocked, cast, colour_to_uint8, frame_boxes, solids

KRAFT = np.array([0.50, 0.36, 0.22])


@dataclass(frozen=True, eq=False)
class Frame:
    rgb: np.ndarray           # HxWx3 uint8
    depth: np.ndarray         # HxW float32 metres, 0 = no measurement
    cam: Cam
    masks: np.ndarray         # HxW uint16, label k = the k-th carton (any of its faces)
    labels: dict              # label -> box id


def _base(scene: dict, cam: Cam) -> tuple[dict, list, dict, np.ndarray]:
    parts, labels = solids(scene)
    hit = cast(cam, parts)
    lab = np.array([p.label for p in parts] + [0])
    masks = lab[hit["idx"]].astype(np.uint16)
    return hit, parts, labels, masks


def _edge_distance(hit: dict, parts: list) -> np.ndarray:
    """Distance (m) from each hit to the nearest edge of the face it lies on."""
    half = np.stack([p.half for p in parts] + [np.ones(3)])[hit["idx"]]
    rest = half - np.abs(hit["local"])
    ax = hit["face"] // 2
    for a in range(3):            # the face's own axis is not an edge direction
        rest[..., a] = np.where(ax == a, np.inf, rest[..., a])
    return rest.min(-1)


def _albedo(hit: dict, parts: list, carton: np.ndarray, boards: np.ndarray) -> np.ndarray:
    """Per-pixel colour: carton k's colour on its faces, the board colour elsewhere."""
    table = np.concatenate([np.stack([carton[p.label - 1] if p.label else boards[i % len(boards)]
                                      for i, p in enumerate(parts)]), np.zeros((1, 3))])
    return table[hit["idx"]]


def _lambert(hit: dict, light: np.ndarray, ambient: float, diffuse: float,
             shadow: np.ndarray | None = None) -> np.ndarray:
    lit = np.clip(hit["normal"] @ light, 0.0, None)
    if shadow is not None:
        lit = np.where(shadow, 0.0, lit)
    return ambient + diffuse * lit


def _depth(hit: dict, rng: np.random.Generator, sigma: float) -> np.ndarray:
    t = np.where(np.isfinite(hit["t"]) & (hit["idx"] >= 0), hit["t"], 0.0)
    return np.where(t > 0, t + rng.normal(0.0, sigma, t.shape), 0.0).astype(np.float32)


def make_flat(scene: dict, rng: np.random.Generator) -> Frame:
    cam = frame_boxes(scene, 640, 480, 560.0, 560.0, rng)
    hit, parts, labels, masks = _base(scene, cam)
    n = len(scene["boxes"])
    carton = np.clip(KRAFT * (1 + rng.normal(0, 0.035, (n, 3))), 0, 1)
    boards = np.array([[0.62, 0.62, 0.60], [0.55, 0.56, 0.57], [0.30, 0.30, 0.32]])
    light = -np.array(cam.rot)[:, 2] + np.array([0.0, 0.0, 0.4])
    shade = _lambert(hit, light / np.linalg.norm(light), 0.5, 0.5)
    seam = np.where(_edge_distance(hit, parts) < 0.003, 0.92, 1.0)
    img = _albedo(hit, parts, carton, boards) * (shade * seam)[..., None]
    img += rng.normal(0, 0.004, img.shape)
    return Frame(colour_to_uint8(img), _depth(hit, rng, 0.0007), cam, masks, labels)


def _design(local: np.ndarray, half: np.ndarray) -> np.ndarray:
    """One printed carton design on the front face (local -y): RGB per hit, from face fractions."""
    u = (local[:, 0] / half[:, 0] + 1) / 2            # 0 left .. 1 right
    v = (local[:, 2] / half[:, 2] + 1) / 2            # 0 bottom .. 1 top
    col = np.tile(np.array([0.80, 0.78, 0.72]), (len(u), 1))
    band = (v > 0.12) & (v < 0.34)
    col[band] = [0.05, 0.12, 0.45]
    logo = (u > 0.08) & (u < 0.30) & (v > 0.55) & (v < 0.85)
    col[logo] = [0.60, 0.06, 0.05]
    rows = (u > 0.40) & (u < 0.90) & (v > 0.50) & (v < 0.88) & (np.floor(v * 40) % 3 == 0)
    col[rows] = [0.08, 0.08, 0.08]
    return col


def make_printed(scene: dict, rng: np.random.Generator) -> Frame:
    cam = frame_boxes(scene, 640, 480, 520.0, 520.0, rng, height_m=1.0)
    hit, parts, labels, masks = _base(scene, cam)
    n = len(scene["boxes"])
    carton = np.tile(np.array([0.72, 0.68, 0.60]), (n, 1))
    boards = np.array([[0.45, 0.45, 0.47], [0.40, 0.40, 0.42], [0.25, 0.24, 0.22]])
    light = np.array([-0.45 + rng.uniform(-0.1, 0.1), -0.55, 0.70])
    light /= np.linalg.norm(light)
    flat_pts = hit["point"].reshape(-1, 3) + hit["normal"].reshape(-1, 3) * 1e-4
    facing = (hit["normal"].reshape(-1, 3) @ light > 0) & (hit["idx"].reshape(-1) >= 0)
    shadow = blocked(flat_pts, light, parts, directional=True, only=facing).reshape(masks.shape)
    img = _albedo(hit, parts, carton, boards)
    front = (masks > 0) & (hit["face"] == 3)           # local y axis entered by its - side: the front
    half = np.stack([p.half for p in parts] + [np.ones(3)])[hit["idx"]]
    img[front] = _design(hit["local"][front], half[front])
    img = img * _lambert(hit, light, 0.10, 1.1, shadow)[..., None]
    img += rng.normal(0, 0.006, img.shape)
    return Frame(colour_to_uint8(img), _depth(hit, rng, 0.001), cam, masks, labels)


def _stereo_depth(hit: dict, parts: list, cam: Cam, rng: np.random.Generator,
                  baseline: float = 0.055) -> np.ndarray:
    """What a stereo camera measures of the exact depth (see the module docstring)."""
    z = np.where(np.isfinite(hit["t"]) & (hit["idx"] >= 0), hit["t"], 0.0)
    right = np.array(cam.pos) + np.array(cam.rot)[:, 0] * baseline
    pts = hit["point"].reshape(-1, 3) + hit["normal"].reshape(-1, 3) * 1e-4
    hidden = blocked(pts, right, parts, directional=False, only=(z > 0).reshape(-1)).reshape(z.shape)
    with np.errstate(divide="ignore"):
        disp = np.where(z > 0, cam.fx * baseline / np.where(z > 0, z, 1.0), 0.0)
    disp = np.round((disp + rng.normal(0, 0.07, z.shape)) * 16) / 16
    out = np.where(disp > 0.5, cam.fx * baseline / np.maximum(disp, 1e-6), 0.0)
    lo = cv2.erode(z.astype(np.float32), np.ones((3, 3), np.uint8))
    hi = cv2.dilate(z.astype(np.float32), np.ones((3, 3), np.uint8))
    edge = (hi - lo > 0.03) & (rng.random(z.shape) < 0.6)
    out = np.where(edge, lo + (hi - lo) * rng.random(z.shape), out)          # flying pixels
    blobs = cv2.resize(rng.random((z.shape[0] // 16, z.shape[1] // 16)).astype(np.float32),
                       (z.shape[1], z.shape[0]), interpolation=cv2.INTER_CUBIC)
    out = np.where(hidden | (blobs > 0.93) | (z > 4.0), 0.0, out)
    return out.astype(np.float32)


def make_stereo(scene: dict, rng: np.random.Generator) -> Frame:
    cam = frame_boxes(scene, 640, 480, 430.0, 430.0, rng, height_m=0.75)
    hit, parts, labels, masks = _base(scene, cam)
    n = len(scene["boxes"])
    tints = np.array([KRAFT, [0.62, 0.50, 0.36], [0.75, 0.74, 0.70], [0.40, 0.28, 0.17]])
    carton = np.clip(tints[rng.integers(0, len(tints), n)] * (1 + rng.normal(0, 0.05, (n, 3))), 0, 1)
    boards = np.array([[0.35, 0.36, 0.40], [0.30, 0.31, 0.34], [0.20, 0.20, 0.20]])
    light = np.array([0.1, -0.35, 1.0])
    shade = _lambert(hit, light / np.linalg.norm(light), 0.35, 0.6)
    img = _albedo(hit, parts, carton, boards) * shade[..., None] * np.array([1.0, 0.97, 0.9])
    h, w = masks.shape
    yy, xx = np.mgrid[0:h, 0:w]
    img *= (1 - 0.35 * (((xx - w / 2) / w) ** 2 + ((yy - h / 2) / h) ** 2))[..., None]
    img = cv2.GaussianBlur(img.astype(np.float32), (0, 0), 0.8) + rng.normal(0, 0.015, img.shape)
    return Frame(colour_to_uint8(img), _stereo_depth(hit, parts, cam, rng), cam, masks, labels)


def _palette_colour(rng: np.random.Generator, dark: bool = False) -> np.ndarray:
    """A saturated print colour (or a dark ink) in linear RGB."""
    hue = rng.uniform(0, 1)
    rgb = np.array(cv2.cvtColor(np.uint8([[[int(hue * 179), 255, 255]]]), cv2.COLOR_HSV2RGB)[0, 0], float) / 255
    rgb = 0.05 + rgb * rng.uniform(0.35, 0.7)
    return rgb * (0.25 if dark else 1.0)


def draw_design(rng: np.random.Generator) -> dict:
    """One printed design for every carton of a frame (the `labels` look): board, bands, logo,
    text rows and a shipping label, each drawn; positions are face fractions or metres."""
    white = rng.random() < 0.5
    board = (np.array([0.78, 0.77, 0.72]) if white else KRAFT * rng.uniform(0.9, 1.25)) * rng.uniform(0.9, 1.05, 3)
    bands = []
    for _ in range(int(rng.integers(0, 3))):
        lo = rng.uniform(0.0, 0.8)
        bands.append((int(rng.random() < 0.25), lo, lo + rng.uniform(0.05, 0.22), _palette_colour(rng)))
    logo = None
    if rng.random() < 0.75:
        u0, v0 = rng.uniform(0.05, 0.6), rng.uniform(0.1, 0.65)
        logo = (u0, u0 + rng.uniform(0.12, 0.3), v0, v0 + rng.uniform(0.12, 0.3), _palette_colour(rng),
                bool(rng.random() < 0.4))
    text = None
    if rng.random() < 0.8:
        u0, v0 = rng.uniform(0.05, 0.5), rng.uniform(0.05, 0.55)
        text = (u0, min(0.97, u0 + rng.uniform(0.25, 0.55)), v0, min(0.97, v0 + rng.uniform(0.15, 0.4)),
                rng.uniform(20, 45), int(rng.integers(2, 4)), rng.uniform(8, 20), int(rng.integers(0, 1 << 30)))
    label = None
    if rng.random() < 0.6:
        label = (rng.uniform(0.08, 0.14), rng.uniform(0.06, 0.10), rng.uniform(0.1, 0.9), rng.uniform(0.2, 0.8))
    return {"board": np.clip(board, 0, 1), "bands": bands, "logo": logo, "text": text, "label": label,
            "ink": np.array([0.04, 0.04, 0.05]) * rng.uniform(0.5, 2.0)}


def _hash01(a: np.ndarray, b: np.ndarray, key: int) -> np.ndarray:
    """A fixed pseudo-random number in [0, 1) per integer pair (glyph cells, bar-code bars)."""
    h = (a.astype(np.int64) * 73856093) ^ (b.astype(np.int64) * 19349663) ^ key
    return ((h * 2654435761) % 1000003) / 1000003.0


def _paint_design(local: np.ndarray, half: np.ndarray, d: dict) -> np.ndarray:
    """The drawn design on front-face hits (local -y face): RGB per hit."""
    u = (local[:, 0] / half[:, 0] + 1) / 2            # 0 left .. 1 right
    v = (local[:, 2] / half[:, 2] + 1) / 2            # 0 bottom .. 1 top
    col = np.tile(d["board"], (len(u), 1))
    for vertical, lo, hi, c in d["bands"]:
        t = u if vertical else v
        col[(t > lo) & (t < hi)] = c
    if d["logo"] is not None:
        u0, u1, v0, v1, c, disc = d["logo"]
        if disc:
            inside = ((u - (u0 + u1) / 2) / ((u1 - u0) / 2)) ** 2 + ((v - (v0 + v1) / 2) / ((v1 - v0) / 2)) ** 2 < 1
        else:
            inside = (u > u0) & (u < u1) & (v > v0) & (v < v1)
        col[inside] = c
    if d["text"] is not None:
        u0, u1, v0, v1, per, every, glyphs, key = d["text"]
        row = np.floor(v * per)
        cell = np.floor(u * per * glyphs / 10)
        ink = ((u > u0) & (u < u1) & (v > v0) & (v < v1) & (row % every == 0)
               & (_hash01(row, cell, key) < 0.72))
        col[ink] = d["ink"]
    if d["label"] is not None:                          # a fixed-size label (metres), centred at drawn fractions
        w, h, cu, cv = d["label"]
        x = local[:, 0] - (cu - 0.5) * 2 * half[:, 0] * 0.6
        z = local[:, 2] - (cv - 0.5) * 2 * half[:, 2] * 0.6
        inside = (np.abs(x) < w / 2) & (np.abs(z) < h / 2)
        col[inside] = [0.86, 0.86, 0.84]
        bars = inside & (z < -h / 6) & (np.abs(x) < w * 0.4) & (_hash01(np.floor(x * 900), np.zeros_like(x), 7) < 0.5)
        lines = inside & (z > 0) & (np.floor(z * 400) % 3 == 0) & (np.abs(x) < w * 0.42)
        col[bars | lines] = [0.03, 0.03, 0.03]
    return col


def make_labels(scene: dict, rng: np.random.Generator) -> Frame:
    """Cartons of one drawn printed design side by side under a hard light of drawn direction."""
    f = float(rng.uniform(480.0, 600.0))
    cam = frame_boxes(scene, 640, 480, f, f, rng, height_m=float(rng.uniform(0.75, 1.05)))
    hit, parts, labels, masks = _base(scene, cam)
    n = len(scene["boxes"])
    d = draw_design(rng)
    grey = rng.uniform(0.2, 0.5)
    boards = np.array([[grey, grey, grey * 1.05], [grey * 0.85] * 3, [grey * 0.5] * 3])
    az = rng.choice([-1.0, 1.0]) * rng.uniform(0.15, 0.9)      # sideways
    light = np.array([az, -rng.uniform(0.3, 0.9), rng.uniform(0.35, 1.1)])
    light /= np.linalg.norm(light)
    flat_pts = hit["point"].reshape(-1, 3) + hit["normal"].reshape(-1, 3) * 1e-4
    facing = (hit["normal"].reshape(-1, 3) @ light > 0) & (hit["idx"].reshape(-1) >= 0)
    shadow = blocked(flat_pts, light, parts, directional=True, only=facing).reshape(masks.shape)
    img = _albedo(hit, parts, np.tile(d["board"], (n, 1)), boards)
    front = (masks > 0) & (hit["face"] == 3)
    half = np.stack([p.half for p in parts] + [np.ones(3)])[hit["idx"]]
    img[front] = _paint_design(hit["local"][front], half[front], d)
    ambient, diffuse = rng.uniform(0.05, 0.3), rng.uniform(0.8, 1.2)
    lit = np.clip(hit["normal"] @ light, 0.0, None)
    dark = rng.uniform(0.6, 1.0)                                # shadow strength: share of direct light lost
    img = img * (ambient + diffuse * lit * np.where(shadow, 1.0 - dark, 1.0))[..., None]
    img += rng.normal(0, rng.uniform(0.003, 0.01), img.shape)
    return Frame(colour_to_uint8(img), _depth(hit, rng, float(rng.uniform(0.0007, 0.0013))), cam, masks, labels)


LOOKS: dict[str, Callable[[dict, np.random.Generator], Frame]] = {
    "flat": make_flat, "printed": make_printed, "stereo": make_stereo, "labels": make_labels}
