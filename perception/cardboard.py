"""Randomised looks of warehouse cardboard: colours, grain, tape, printed labels.

The synthetic renders are the segmenter's training data and the built-in demo,
so they must vary what a real warehouse varies, or a model trained on them
learns one brown. Everything here is a pure function of a numpy Generator:
same seed, same textures. Textures are small (64-128 px) so PyBullet's
TinyRenderer stays fast; each is mapped once onto every face of a box.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

# RGB base colours seen on shelves: kraft browns, tans, bleached white, grey-brown
CARDBOARD_RGB: tuple[tuple[int, int, int], ...] = (
    (181, 137, 92), (196, 154, 108), (166, 123, 81), (205, 170, 125), (150, 111, 74),
    (214, 184, 140), (226, 210, 180), (238, 234, 226), (245, 243, 238), (172, 150, 120),
    (139, 104, 70), (190, 160, 120),
)
TAPE_RGB: tuple[tuple[int, int, int], ...] = (
    (200, 160, 90), (170, 120, 60), (235, 230, 215), (225, 225, 225), (60, 60, 60),
    (200, 60, 50), (60, 90, 170), (230, 190, 60),
)
INK_RGB: tuple[tuple[int, int, int], ...] = ((25, 25, 25), (40, 40, 90), (120, 30, 30), (30, 80, 40))


def _jitter(rgb: tuple[int, int, int], rng: np.random.Generator, amount: float) -> np.ndarray:
    return np.clip(np.asarray(rgb, float) * rng.uniform(1 - amount, 1 + amount)
                   + rng.normal(0, 6, 3), 0, 255)


def box_texture(rng: np.random.Generator, size: int = 96) -> np.ndarray:
    """One box's texture (size x size x 3 uint8 RGB): cardboard, maybe tape and labels."""
    h = w = size
    base = _jitter(CARDBOARD_RGB[rng.integers(len(CARDBOARD_RGB))], rng, 0.12)
    img = np.empty((h, w, 3), float)
    img[:] = base
    # paper grain and corrugation (faint stripes along one axis)
    img += rng.normal(0, rng.uniform(2, 7), (h, w, 1))
    if rng.random() < 0.6:
        period = rng.uniform(2.5, 5.0)
        stripes = np.sin(np.arange(w if rng.random() < 0.5 else h) * 2 * np.pi / period)
        amp = rng.uniform(1, 4)
        img += (stripes[None, :, None] if stripes.size == w else stripes[:, None, None]) * amp
    # a smooth stain/shade gradient
    yy, xx = np.mgrid[0:h, 0:w] / size
    img *= (1 + rng.uniform(-0.08, 0.08) * (xx - 0.5) + rng.uniform(-0.08, 0.08) * (yy - 0.5))[:, :, None]
    # tape: a band through the middle, vertical or horizontal, sometimes both
    if rng.random() < 0.7:
        tape = _jitter(TAPE_RGB[rng.integers(len(TAPE_RGB))], rng, 0.08)
        width = int(rng.uniform(0.10, 0.22) * size)
        choice = rng.random()
        if choice < 0.6 or choice >= 0.85:
            x0 = int(size / 2 - width / 2 + rng.integers(-2, 3))
            img[:, x0:x0 + width] = img[:, x0:x0 + width] * 0.25 + tape * 0.75
        if choice >= 0.6:
            y0 = int(size / 2 - width / 2 + rng.integers(-2, 3))
            img[y0:y0 + width, :] = img[y0:y0 + width, :] * 0.25 + tape * 0.75
    # printed shipping label: white card, barcode bars, text lines
    for _ in range(rng.integers(0, 3)):
        lw, lh = int(rng.uniform(0.18, 0.4) * size), int(rng.uniform(0.12, 0.3) * size)
        x0, y0 = rng.integers(2, max(3, w - lw - 2)), rng.integers(2, max(3, h - lh - 2))
        paper = _jitter((245, 245, 240), rng, 0.04) if rng.random() < 0.8 else \
            _jitter((240, 220, 120), rng, 0.05)
        img[y0:y0 + lh, x0:x0 + lw] = paper
        ink = np.asarray(INK_RGB[rng.integers(len(INK_RGB))], float)
        if rng.random() < 0.6:  # barcode
            bars = rng.random(lw - 4) < 0.45
            by0, by1 = y0 + 2, y0 + max(3, lh // 2)
            cols = np.nonzero(bars)[0] + x0 + 2
            img[by0:by1, cols] = ink
        for k in range(rng.integers(1, 4)):  # text lines
            ty = y0 + lh - 3 - 3 * k
            if ty <= y0 + 1:
                break
            tx1 = x0 + 2 + int(rng.uniform(0.3, 0.9) * (lw - 4))
            img[ty:ty + 1, x0 + 2:tx1] = ink
    # printed logo / handling marks directly on the cardboard
    if rng.random() < 0.35:
        ink = np.asarray(INK_RGB[rng.integers(len(INK_RGB))], float)
        s = int(rng.uniform(0.08, 0.18) * size)
        x0, y0 = rng.integers(2, w - s - 2), rng.integers(2, h - s - 2)
        img[y0:y0 + s, x0:x0 + s] = img[y0:y0 + s, x0:x0 + s] * 0.4 + ink * 0.6
    # darker edges, as folds and worn corners read on a real carton
    edge = max(1, size // 40)
    dark = rng.uniform(0.75, 0.95)
    img[:edge] *= dark
    img[-edge:] *= dark
    img[:, :edge] *= dark
    img[:, -edge:] *= dark
    return np.clip(img, 0, 255).astype(np.uint8)


def plain_box_texture(rng: np.random.Generator, size: int = 96) -> np.ndarray:
    """Plain cardboard (size x size x 3 uint8 RGB): a kraft or white tone with grain, maybe
    corrugation, a shade gradient and darker edges; no tape, no label, no print. Why: the
    rules were fitted to printed and taped boxes; a plain face has no inner edge to lean on."""
    h = w = size
    tones = CARDBOARD_RGB[:6] + CARDBOARD_RGB[9:]
    img = np.empty((h, w, 3), float)
    img[:] = _jitter(tones[rng.integers(len(tones))], rng, 0.08)
    img += rng.normal(0, rng.uniform(1, 5), (h, w, 1))
    if rng.random() < 0.5:
        stripes = np.sin(np.arange(w) * 2 * np.pi / rng.uniform(2.5, 5.0)) * rng.uniform(1, 3)
        img += stripes[None, :, None]
    yy, xx = np.mgrid[0:h, 0:w] / size
    img *= (1 + rng.uniform(-0.1, 0.1) * (xx - 0.5) + rng.uniform(-0.1, 0.1) * (yy - 0.5))[:, :, None]
    edge = max(1, size // 40)
    dark = rng.uniform(0.85, 0.98)
    for sl in (np.s_[:edge], np.s_[-edge:], np.s_[:, :edge], np.s_[:, -edge:]):
        img[sl] *= dark
    return np.clip(img, 0, 255).astype(np.uint8)


def plain_texture(rng: np.random.Generator, rgb: tuple[int, int, int], size: int = 32,
                  grain: float = 4.0) -> np.ndarray:
    """A flat colour with some grain (shelf boards, walls, background)."""
    import cv2

    img = np.empty((size, size, 3), float)
    img[:] = _jitter(rgb, rng, 0.1)
    img += cv2.GaussianBlur(rng.normal(0, grain, (size, size)), (5, 5), 1.5)[:, :, None]
    return np.clip(img, 0, 255).astype(np.uint8)


SHELF_RGB: tuple[tuple[int, int, int], ...] = (
    (150, 150, 155), (110, 110, 115), (60, 65, 75), (190, 160, 110), (170, 120, 70),
    (210, 210, 205), (80, 100, 140), (200, 110, 40),
)
BACKGROUND_RGB: tuple[tuple[int, int, int], ...] = (
    (90, 90, 95), (140, 140, 135), (200, 200, 195), (60, 70, 60), (120, 100, 80), (40, 40, 45),
)


def write_png(path: str | Path, img: np.ndarray) -> Path:
    """Write an RGB texture as PNG (for `loadTexture`)."""
    import cv2

    p = Path(path)
    cv2.imwrite(str(p), np.ascontiguousarray(img[:, :, ::-1]))
    return p


__all__ = ["box_texture", "plain_box_texture", "plain_texture", "write_png", "CARDBOARD_RGB", "SHELF_RGB", "BACKGROUND_RGB"]
