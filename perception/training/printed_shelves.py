"""Shelves of flush cartons that share one print, under one hard directional light (fifth round).

What the learned segmenter had not seen in training (issue 31): RGB-D SHELVES (not photo
walls) where every carton of a frame carries the same design side by side, so the seam
between two cartons is the only cue and the print's own bands, blocks and text edges are
not; lit by one strong light from a side, with hard shadows across faces. Everything is drawn
here, generically and broadly, by our own renderer (`perception/render.py`): design families
(bands, a panel, a logo, a shipping label, a pattern, a product picture) on kraft, white or
coloured board; one light direction, strength and shadow per frame; shadow edges laid over
the image. The label stays each carton's whole visible front face (`front_face_masks`): a
band, a print edge or a shadow edge never ends a carton.

`printed_shelf_example(seed)` -> (RGB uint8, front-face instance labels uint16), seeds >=
`PRINTED_SEED0` (34000: after every earlier round's range and every fixed role);
`printed_shelf_capture(seed)` -> (Capture with depth, Scene).
"""
from __future__ import annotations

import math
import string
from dataclasses import dataclass

import cv2
import numpy as np

from shelfpick.perception.capture import Capture
from shelfpick.perception.cardboard import CARDBOARD_RGB, box_texture, plain_box_texture
from shelfpick.perception.evaluation.truth import front_face_masks
from shelfpick.perception.geometry import matrix_to_quat
from shelfpick.perception.render import default_camera, render
from shelfpick.perception.scene import Box, Camera, Scene, Shelf

PRINTED_SEED0 = 34000
SHARED_DESIGN = 0.85          # share of frames whose cartons all carry one design
FAMILIES = ("bands", "panel", "logo", "label", "pattern", "picture")
_FONTS = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
          cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_PLAIN, cv2.FONT_HERSHEY_COMPLEX_SMALL)


def _colour(rng: np.random.Generator) -> np.ndarray:
    """Any saturated or dark colour (HSV drawn uniformly)."""
    hsv = np.uint8([[[rng.integers(180), rng.integers(90, 256), rng.integers(40, 240)]]])
    return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)[0, 0].astype(np.float32)


def _board(rng: np.random.Generator, size: int) -> np.ndarray:
    """The printed-on board: kraft (textured or plain), white, or a flood colour."""
    r = rng.random()
    if r < 0.35:
        img = cv2.resize(plain_box_texture(rng, 64), (size, size), interpolation=cv2.INTER_LINEAR)
        return img.astype(np.float32)
    if r < 0.5:
        return cv2.resize(box_texture(rng, 96), (size, size), interpolation=cv2.INTER_LINEAR).astype(np.float32)
    if r < 0.8:
        base = np.float32(rng.uniform(215, 250)) * rng.uniform(0.96, 1.04, 3).astype(np.float32)
    else:
        base = _colour(rng)
    img = np.empty((size, size, 3), np.float32)
    img[:] = base
    return img + rng.normal(0, rng.uniform(1, 5), (size, size, 1)).astype(np.float32)


def _text(img: np.ndarray, rng: np.random.Generator, ink: np.ndarray, rows: int, y_range=(0.1, 0.95)) -> None:
    """Rows of random upper-case words and numbers (no fixed vocabulary)."""
    s = img.shape[0]
    u8 = np.clip(img, 0, 255).astype(np.uint8)          # putText draws on 8-bit images only
    for _ in range(rows):
        n = int(rng.integers(2, 12))
        word = "".join(rng.choice(list(string.ascii_uppercase + string.digits + "  -"), n))
        scale = float(rng.uniform(0.3, 1.8)) * s / 256
        thick = max(1, int(rng.uniform(1, 4) * s / 256))
        org = (int(rng.uniform(0.0, 0.6) * s), int(rng.uniform(*y_range) * s))
        cv2.putText(u8, word, org, _FONTS[int(rng.integers(len(_FONTS)))], scale,
                    tuple(int(v) for v in ink), thick, cv2.LINE_AA)
    img[:] = u8


def _logo(img: np.ndarray, rng: np.random.Generator, col: np.ndarray) -> None:
    """A mark: disc, ring, triangle, diamond, star or a letter in a square."""
    s = img.shape[0]
    r = int(rng.uniform(0.06, 0.22) * s)
    c = np.array([rng.uniform(0.2, 0.8) * s, rng.uniform(0.2, 0.8) * s])
    kind = int(rng.integers(6))
    colt = tuple(float(v) for v in col)
    if kind == 0:
        cv2.circle(img, (int(c[0]), int(c[1])), r, colt, -1, cv2.LINE_AA)
    elif kind == 1:
        cv2.circle(img, (int(c[0]), int(c[1])), r, colt, max(2, r // 4), cv2.LINE_AA)
    elif kind in (2, 3, 4):
        n = (3, 4, 10)[kind - 2]
        a0 = float(rng.uniform(0, 2 * math.pi))
        radii = [r if (kind != 4 or k % 2 == 0) else r * 0.45 for k in range(n)]
        pts = np.array([[c[0] + q * math.cos(a0 + 2 * math.pi * k / n), c[1] + q * math.sin(a0 + 2 * math.pi * k / n)]
                        for k, q in enumerate(radii)], np.int32)
        cv2.fillPoly(img, [pts], colt, cv2.LINE_AA)
    else:
        cv2.rectangle(img, (int(c[0] - r), int(c[1] - r)), (int(c[0] + r), int(c[1] + r)), colt, -1)
        u8 = np.clip(img, 0, 255).astype(np.uint8)
        cv2.putText(u8, str(rng.choice(list(string.ascii_uppercase))), (int(c[0] - r * 0.7), int(c[1] + r * 0.7)),
                    cv2.FONT_HERSHEY_DUPLEX, r / 16, (245, 245, 245), max(1, r // 8), cv2.LINE_AA)
        img[:] = u8


def _bands(img: np.ndarray, rng: np.random.Generator) -> None:
    """1-3 coloured bands right across the face (to its edges), along or across, any width."""
    s = img.shape[0]
    across = rng.random() < 0.7
    for _ in range(int(rng.integers(1, 4))):
        a = int(rng.uniform(0.0, 0.9) * s)
        b = a + max(2, int(rng.uniform(0.03, 0.3) * s))
        sl = np.s_[a:b] if across else np.s_[:, a:b]
        img[sl] = img[sl] * rng.uniform(0.0, 0.3) + _colour(rng) * rng.uniform(0.7, 1.0)


def _panel(img: np.ndarray, rng: np.random.Generator) -> None:
    """A big coloured panel (most of the face, or one side of it) with a light window."""
    s = img.shape[0]
    x0, y0 = (int(rng.uniform(0.0, 0.3) * s) for _ in range(2))
    x1, y1 = (int(rng.uniform(0.6, 1.0) * s) for _ in range(2))
    img[y0:y1, x0:x1] = _colour(rng)
    if rng.random() < 0.7:
        wx0, wy0 = x0 + (x1 - x0) // 6, y0 + (y1 - y0) // 4
        wx1, wy1 = x1 - (x1 - x0) // int(rng.integers(3, 7)), y1 - (y1 - y0) // int(rng.integers(3, 7))
        img[wy0:wy1, wx0:wx1] = rng.uniform(220, 250)


def _label(img: np.ndarray, rng: np.random.Generator, ink: np.ndarray) -> None:
    """A white shipping label with a bar code and text lines, anywhere (maybe at an edge)."""
    s = img.shape[0]
    lw, lh = int(rng.uniform(0.2, 0.5) * s), int(rng.uniform(0.15, 0.4) * s)
    x0, y0 = int(rng.integers(0, s - lw)), int(rng.integers(0, s - lh))
    img[y0:y0 + lh, x0:x0 + lw] = rng.uniform(228, 252)
    bars = np.nonzero(rng.random(max(1, lw - 8)) < 0.5)[0] + x0 + 4
    img[y0 + 4:y0 + max(6, lh // 2), bars] = ink
    for k in range(int(rng.integers(1, 4))):
        ty = y0 + lh // 2 + 4 + k * max(3, lh // 8)
        if ty + 2 < y0 + lh:
            img[ty:ty + max(1, lh // 18), x0 + 4:x0 + 4 + int(rng.uniform(0.3, 0.9) * (lw - 8))] = ink


def _pattern(img: np.ndarray, rng: np.random.Generator) -> None:
    """Stripes, checks or dots over the whole face (a repeating print)."""
    s = img.shape[0]
    yy, xx = np.mgrid[0:s, 0:s].astype(np.float32)
    period = float(rng.uniform(0.06, 0.3)) * s
    a = float(rng.uniform(0, math.pi))
    u = xx * math.cos(a) + yy * math.sin(a)
    kind = int(rng.integers(3))
    if kind == 0:
        on = (u % period) < period * rng.uniform(0.2, 0.6)
    elif kind == 1:
        v = -xx * math.sin(a) + yy * math.cos(a)
        on = ((u // period) + (v // period)) % 2 == 0
    else:
        on = ((xx % period - period / 2) ** 2 + (yy % period - period / 2) ** 2) < (period * rng.uniform(0.15, 0.4)) ** 2
    img[on] = img[on] * 0.2 + _colour(rng) * 0.8


def _picture(img: np.ndarray, rng: np.random.Generator) -> None:
    """A product picture: soft colour blobs in a frame, as photos printed on retail cartons."""
    s = img.shape[0]
    x0, y0 = int(rng.uniform(0.05, 0.4) * s), int(rng.uniform(0.05, 0.4) * s)
    x1, y1 = int(rng.uniform(0.6, 0.95) * s), int(rng.uniform(0.6, 0.95) * s)
    pic = np.empty((y1 - y0, x1 - x0, 3), np.float32)
    pic[:] = _colour(rng)
    for _ in range(int(rng.integers(2, 7))):
        c = (int(rng.integers(0, x1 - x0)), int(rng.integers(0, y1 - y0)))
        ax = (int(rng.integers(3, max(4, (x1 - x0) // 2))), int(rng.integers(3, max(4, (y1 - y0) // 2))))
        cv2.ellipse(pic, c, ax, float(rng.uniform(0, 180)), 0, 360, tuple(float(v) for v in _colour(rng)), -1)
    img[y0:y1, x0:x1] = cv2.GaussianBlur(pic, (0, 0), float(rng.uniform(1, 6)))


def design_texture(rng: np.random.Generator, size: int = 256, family: str | None = None) -> np.ndarray:
    """One carton design (size x size RGB uint8): a board, one family's main print, and maybe
    text rows, a logo and a label on top; the border darkened or not (some prints run to it)."""
    family = family or FAMILIES[int(rng.integers(len(FAMILIES)))]
    img = _board(rng, size)
    ink = np.float32([rng.uniform(10, 60)] * 3) if rng.random() < 0.6 else _colour(rng) * 0.6
    {"bands": lambda: _bands(img, rng), "panel": lambda: _panel(img, rng), "logo": lambda: _logo(img, rng, _colour(rng)),
     "label": lambda: _label(img, rng, ink), "pattern": lambda: _pattern(img, rng),
     "picture": lambda: _picture(img, rng)}[family]()
    if rng.random() < 0.7:
        _text(img, rng, ink, int(rng.integers(1, 6)))
    if family != "logo" and rng.random() < 0.4:
        _logo(img, rng, _colour(rng) if rng.random() < 0.5 else ink)
    if family != "label" and rng.random() < 0.3:
        _label(img, rng, ink)
    if rng.random() < 0.6:
        edge = max(1, int(rng.uniform(0.004, 0.025) * size))
        dark = float(rng.uniform(0.5, 0.95))
        for sl in (np.s_[:edge], np.s_[-edge:], np.s_[:, :edge], np.s_[:, -edge:]):
            img[sl] *= dark
    return np.clip(img, 0, 255).astype(np.uint8)


def _copy(tex: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The shared design on one more carton: brightness within 6 %, turned 180 deg sometimes."""
    out = tex.astype(np.float32) * float(rng.uniform(0.94, 1.06))
    if rng.random() < 0.15:
        out = out[::-1, ::-1]
    return np.clip(out, 0, 255).astype(np.uint8)


def _quat_z(deg: float) -> tuple[float, float, float, float]:
    a = math.radians(deg)
    m = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])
    return tuple(float(v) for v in matrix_to_quat(m))  # type: ignore[return-value]


def printed_shelf_scene(rng: np.random.Generator) -> Scene:
    """A shelf bay of cartons in flush columns: one carton size per section (1-2 sections),
    gaps 0-6 mm, stacked to a drawn height (the top row may miss cartons), fronts within 1.5 cm
    of the shelf front, a few proud (up to 6 cm: they cast shadows) or turned up to 4 deg."""
    shelf = Shelf(float(rng.uniform(0.8, 1.6)), float(rng.uniform(0.3, 0.6)), float(rng.uniform(0.6, 1.6)))
    boxes: list[Box] = []
    x = -shelf.width / 2 + float(rng.uniform(0.0, 0.04))
    sections = int(rng.integers(1, 3))
    sec_end = [x + (shelf.width - 0.04) * (k + 1) / sections for k in range(sections)]
    for end in sec_end:
        w, h = float(rng.uniform(0.15, 0.5)), float(rng.uniform(0.1, 0.4))
        d = float(rng.uniform(0.15, shelf.depth - 0.01))
        gap = float(rng.uniform(0.0, 0.006))
        top = float(rng.uniform(0.4, 1.0)) * (shelf.height - 0.05)
        while x + w <= min(end, shelf.width / 2):
            z = 0.0
            while z + h <= max(top, h):
                if z > 0 and z + 2 * h > top and rng.random() < 0.3:
                    break
                front = float(rng.uniform(0.0, 0.015))
                if rng.random() < 0.08:
                    front = -float(rng.uniform(0.02, 0.06))                    # proud
                yaw = float(rng.uniform(-4, 4)) if rng.random() < 0.2 else 0.0
                boxes.append(Box(f"b{len(boxes)}", (w, d, h), (x + w / 2, front + d / 2, z + h / 2), _quat_z(yaw)))
                z += h + float(rng.uniform(0.0, 0.004))
            x += w + gap
        x += float(rng.uniform(0.0, 0.03))
    return Scene(shelf, tuple(boxes), None, {"kind": "train-printed-shelf"})


def printed_shelf_camera(rng: np.random.Generator, scene: Scene) -> Camera:
    """640x480, 0.8-1.9 m before the shelf, 0.4-1.4 m up, up to 0.3 m to a side, aimed at a point
    of the stack's front, rolled up to 3 deg, focal 0.75-1.05 x the width."""
    zs = [b.position[2] for b in scene.boxes] or [0.3]
    aim = np.array([rng.uniform(-0.2, 0.2) * scene.shelf.width, 0.0, rng.uniform(min(zs), max(zs) + 0.05)])
    pos = np.array([rng.uniform(-0.3, 0.3), -rng.uniform(0.8, 1.9), rng.uniform(0.4, 1.4)])
    zax = (aim - pos) / np.linalg.norm(aim - pos)
    xax = np.cross(zax, [0.0, 0.0, 1.0])
    xax /= np.linalg.norm(xax)
    a = math.radians(float(rng.uniform(-3, 3)))
    roll = np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1.0]])
    r = np.stack([xax, np.cross(zax, xax), zax], axis=1) @ roll
    f = float(rng.uniform(0.75, 1.05)) * 640
    base = default_camera()
    return Camera(640, 480, f, f, 319.5 + float(rng.uniform(-8, 8)), 239.5 + float(rng.uniform(-8, 8)),
                  base.depth_scale, tuple(float(v) for v in pos), tuple(float(v) for v in matrix_to_quat(r)))  # type: ignore[arg-type]


def hard_light(rng: np.random.Generator) -> dict:
    """One strong light from the left or right, high or low, little ambient, shadows on."""
    side = 1.0 if rng.random() < 0.5 else -1.0
    direction = [side * float(rng.uniform(0.3, 2.0)), -float(rng.uniform(0.6, 2.5)), float(rng.uniform(0.0, 3.0))]
    warm = float(rng.uniform(-0.1, 0.1))
    return {"lightDirection": direction, "lightColor": [1.0 + warm, 1.0, 1.0 - warm], "lightDistance": 3.0,
            "shadow": 1, "lightAmbientCoeff": float(rng.uniform(0.08, 0.4)),
            "lightDiffuseCoeff": float(rng.uniform(0.6, 1.0)), "lightSpecularCoeff": float(rng.uniform(0.0, 0.25))}


def cast_shadows(rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """0-3 hard shadows laid over the image (of things outside the frame or above the shelf):
    half-planes or slanted quadrilaterals, 25-75 % of the light lost, edges sharp to 2 px.
    Colour only: no label and no depth changes."""
    h, w = rgb.shape[:2]
    shade = np.ones((h, w), np.float32)
    for _ in range(int(rng.choice([0, 1, 1, 2, 3]))):
        m = np.zeros((h, w), np.uint8)
        if rng.random() < 0.5:
            a = float(rng.uniform(0, 2 * math.pi))
            yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
            m[(xx - w / 2) * math.cos(a) + (yy - h / 2) * math.sin(a) > float(rng.uniform(-0.4, 0.4)) * w] = 1
        else:
            x0, y0 = float(rng.uniform(-0.2, 0.9)) * w, float(rng.uniform(-0.2, 0.9)) * h
            bw, bh, sh = float(rng.uniform(0.1, 0.6)) * w, float(rng.uniform(0.1, 0.6)) * h, float(rng.uniform(-0.5, 0.5))
            pts = np.array([[x0, y0], [x0 + bw, y0], [x0 + bw + sh * bh, y0 + bh], [x0 + sh * bh, y0 + bh]], np.int32)
            cv2.fillPoly(m, [pts], 1)
        soft = m.astype(np.float32)
        blur = float(rng.uniform(0.0, 1.0))
        if blur > 0.3:
            soft = cv2.GaussianBlur(soft, (0, 0), blur)
        shade *= 1.0 - float(rng.uniform(0.25, 0.75)) * soft
    return np.clip(rgb.astype(np.float32) * shade[..., None], 0, 255).astype(np.uint8)


@dataclass(frozen=True)
class PrintedFrame:
    """What frame `seed` shows, before rendering: the shelf, the camera, each carton's texture
    (copies of one design when `shared`), the light, and the seed of the shadows laid over."""

    scene: Scene
    camera: Camera
    textures: tuple[np.ndarray, ...]
    shared: bool
    light: dict
    shadow_seed: int


def printed_frame(seed: int) -> PrintedFrame:
    """Draw frame `seed` (>= `PRINTED_SEED0`): same seed, same frame."""
    if seed < PRINTED_SEED0:
        raise ValueError(f"printed shelf frames use seeds >= {PRINTED_SEED0}, got {seed}")
    rng = np.random.default_rng(seed + 3_000_017)
    scene = printed_shelf_scene(rng)
    cam = printed_shelf_camera(rng, scene)
    size = int(rng.choice([128, 192, 256]))
    shared = bool(rng.random() < SHARED_DESIGN)
    if shared:
        design = design_texture(rng, size)
        textures = [_copy(design, rng) for _ in scene.boxes]
    else:                                          # a few designs, cartons of a column alike
        designs = [design_texture(rng, size) for _ in range(int(rng.integers(2, 4)))]
        textures = [_copy(designs[int(round(b.position[0] * 7)) % len(designs)], rng) for b in scene.boxes]
    return PrintedFrame(scene, cam, tuple(textures), shared, hard_light(rng), seed + 5_000_011)


def printed_shelf_capture(seed: int, shadows: bool = True) -> tuple[Capture, Scene]:
    """The frame of `seed` as a Capture (RGB, noisy depth, true masks); `shadows`: the hard
    shadows of `cast_shadows` laid over the colour image (never over depth or masks)."""
    fr = printed_frame(seed)
    cap = render(fr.scene, fr.camera, seed=seed, looks="printed", textures=fr.textures, light=fr.light)
    rgb = cast_shadows(cap.rgb, np.random.default_rng(fr.shadow_seed)) if shadows else cap.rgb
    return Capture(rgb, cap.depth, cap.camera, cap.masks, cap.labels), fr.scene


def printed_shelf_example(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 HxWx3, front-face instance labels uint16) of training frame `seed`."""
    cap, scene = printed_shelf_capture(seed)
    labels = np.zeros(cap.shape, np.uint16)
    for k, m in enumerate(front_face_masks(scene, cap).values(), start=1):
        labels[m] = k
    return cap.rgb, labels
