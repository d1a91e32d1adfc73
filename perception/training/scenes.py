"""Photo-like training scenes for the learned segmenter (issue 14, second and fourth training rounds).

What the real carton photos have and the first round's renders lacked: walls and rows of
flush cartons of the SAME print side by side (the seam between two only a thin darker line
or a gap of a few millimetres), big prints (text, bands, logos) across a face, a camera
0.9-3.2 m away that may look from below or from above, portrait frames. Generic variety
only: sizes, prints, gaps, camera poses are all drawn at random; no real image is read.

`wall_example(seed)` -> (RGB uint8, front-face instance labels uint16); seeds >= 30800 (the
first round used 30000-30799; every fixed role lives below 30000).

Fourth round: `taped_wall_example(seed)`, seeds >= 32000, the same walls with each carton's face
cut by what cuts real ones: wide tape bands and crosses anywhere on the face (opaque or clear),
stickers of any size that may run to the face's border, and a hard shadow edge across the face.
The label is still the whole front face: none of these ends a carton.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from shelfpick.perception.evaluation.truth import front_face_masks
from shelfpick.perception.cardboard import INK_RGB, TAPE_RGB, box_texture, plain_box_texture
from shelfpick.perception.geometry import matrix_to_quat
from shelfpick.perception.render import default_camera, render
from shelfpick.perception.scene import Box, Camera, Scene, Shelf

WALL_SEED0 = 30800
TAPED_SEED0 = 32000     # fourth round: walls whose faces are cut by tape, stickers, shadows

_WORDS = ("CARTON", "FRAGILE", "THIS SIDE UP", "MADE IN", "NET WT", "12 x 500ml", "AB-2041", "LOT 2021",
          "EXPORT", "PHARMA", "FOOD", "SAFETY", "KEEP DRY", "0.9%", "250ml", "18AA", "Co. Ltd", "ORGANIC")


def printed_texture(rng: np.random.Generator, size: int = 256) -> np.ndarray:
    """A carton face with a big print: cardboard (or white board), a few lines of large
    text, maybe a coloured band or block, a logo mark; edges darkened by a random amount."""
    base = box_texture(rng, size) if rng.random() < 0.5 else plain_box_texture(rng, size)
    img = base.astype(np.float32)
    if rng.random() < 0.2:                                    # white / bleached board
        img = img * 0.3 + np.array([235, 232, 225], np.float32) * rng.uniform(0.6, 0.75)
    ink = np.asarray(INK_RGB[rng.integers(len(INK_RGB))], np.float32)
    col = rng.integers(0, 256, 3).astype(np.float32)
    if rng.random() < 0.4:                                    # a coloured band across the face
        y0 = int(rng.uniform(0.0, 0.8) * size)
        bh = int(rng.uniform(0.06, 0.25) * size)
        img[y0:y0 + bh] = img[y0:y0 + bh] * 0.2 + col * 0.8
    if rng.random() < 0.3:                                    # a coloured block in a corner
        bw, bh = int(rng.uniform(0.1, 0.3) * size), int(rng.uniform(0.1, 0.3) * size)
        x0 = 0 if rng.random() < 0.5 else size - bw
        y0 = 0 if rng.random() < 0.5 else size - bh
        img[y0:y0 + bh, x0:x0 + bw] = img[y0:y0 + bh, x0:x0 + bw] * 0.3 + col[::-1] * 0.7
    u8 = np.clip(img, 0, 255).astype(np.uint8)
    fonts = (cv2.FONT_HERSHEY_SIMPLEX, cv2.FONT_HERSHEY_DUPLEX, cv2.FONT_HERSHEY_COMPLEX,
             cv2.FONT_HERSHEY_TRIPLEX, cv2.FONT_HERSHEY_PLAIN)
    for _ in range(int(rng.integers(1, 6))):                  # lines of text, large and small
        text = _WORDS[int(rng.integers(len(_WORDS)))]
        scale = float(rng.uniform(0.3, 1.6)) * size / 256
        thick = max(1, int(rng.uniform(1, 4) * size / 256))
        org = (int(rng.uniform(0.02, 0.5) * size), int(rng.uniform(0.1, 0.98) * size))
        c = ink if rng.random() < 0.7 else col
        cv2.putText(u8, text, org, fonts[int(rng.integers(len(fonts)))], scale, tuple(int(v) for v in c), thick,
                    cv2.LINE_AA)
    if rng.random() < 0.4:                                    # a logo: circle or ring
        r = int(rng.uniform(0.04, 0.12) * size)
        ctr = (int(rng.uniform(0.15, 0.85) * size), int(rng.uniform(0.15, 0.85) * size))
        cv2.circle(u8, ctr, r, tuple(int(v) for v in ink), -1 if rng.random() < 0.5 else max(1, r // 4))
    img = u8.astype(np.float32)
    edge = max(1, int(rng.uniform(0.005, 0.03) * size))
    dark = float(rng.uniform(0.45, 0.95))
    for sl in (np.s_[:edge], np.s_[-edge:], np.s_[:, :edge], np.s_[:, -edge:]):
        img[sl] *= dark
    return np.clip(img, 0, 255).astype(np.uint8)


def _group_texture(rng: np.random.Generator) -> np.ndarray:
    r = rng.random()
    if r < 0.6:
        return printed_texture(rng, int(rng.choice([192, 256])))
    if r < 0.85:
        return box_texture(rng, int(rng.choice([96, 128])))
    return plain_box_texture(rng, int(rng.choice([64, 96])))


def _variant(tex: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """The same print on another carton of the group: a little brighter or darker, maybe a
    shipping label stuck somewhere."""
    out = tex.astype(np.float32) * float(rng.uniform(0.92, 1.08))
    if rng.random() < 0.3:
        s = tex.shape[0]
        lw, lh = int(rng.uniform(0.12, 0.3) * s), int(rng.uniform(0.08, 0.2) * s)
        x0, y0 = int(rng.integers(2, s - lw - 2)), int(rng.integers(2, s - lh - 2))
        out[y0:y0 + lh, x0:x0 + lw] = rng.uniform(225, 250)
    return np.clip(out, 0, 255).astype(np.uint8)


def _rot_z(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def wall_scene(rng: np.random.Generator) -> tuple[Scene, list[int]]:
    """A wall of cartons in sections: each section one carton size and one print group, rows
    stacked flush (gaps 0-8 mm, sometimes a brick offset), fronts within 2 cm of each other,
    turned up to 3 deg; the top row may be short. Returns the scene and each box's print group."""
    width = float(rng.uniform(1.0, 2.6))
    height = float(rng.uniform(1.1, 2.0))
    shelf = Shelf(width, 0.65, height)
    boxes: list[Box] = []
    groups: list[int] = []
    x = -width / 2 + float(rng.uniform(0.0, 0.03))
    n_groups = int(rng.integers(1, 4))
    top = float(rng.uniform(0.55, 1.0)) * (height - 0.04)
    while x < width / 2 - 0.15:
        g = int(rng.integers(n_groups))
        w = float(rng.uniform(0.18, 0.6))
        h = float(rng.uniform(0.12, 0.45))
        d = float(rng.uniform(0.2, 0.6))
        cols = int(rng.integers(1, 5))
        gap = float(rng.uniform(0.0, 0.008))
        sec_w = min(cols * (w + gap), width / 2 - x)
        cols = max(1, int(sec_w // (w + gap)))
        if x + w > width / 2:
            break
        brick = rng.random() < 0.25
        z = 0.0
        row = 0
        while z + h <= top:
            off = (w / 2 if brick and row % 2 else 0.0)
            for c in range(cols):
                cx = x + off + c * (w + gap) + w / 2
                if cx + w / 2 > width / 2 or (row > 0 and z + h > top - h and rng.random() < 0.25):
                    continue
                front = float(rng.uniform(0.0, 0.02))
                r = _rot_z(math.radians(float(rng.uniform(-3, 3)))) if rng.random() < 0.5 else np.eye(3)
                boxes.append(Box(f"b{len(boxes)}", (w, d, h), (cx, front + d / 2, z + h / 2),
                                 tuple(float(v) for v in matrix_to_quat(r))))  # type: ignore[arg-type]
                groups.append(g)
            z += h + float(rng.uniform(0.0, 0.006))
            row += 1
        x += cols * (w + gap) + (w / 2 if brick else 0.0) + float(rng.uniform(0.0, 0.03))
    return Scene(shelf, tuple(boxes), None, {"kind": "train-wall"}), groups


def wall_camera(rng: np.random.Generator, scene: Scene) -> Camera:
    """Aimed at a point of the wall, from a distance at which the view spans 0.45-1.4 x the
    wall's width (0.9-3.2 m, so the wall fills the frame or sits in it), 0.2-2.6 m up (from
    below to from above), up to 1.2 m to a side; rolled up to 5 deg; landscape 640x480 or
    portrait 480x640; focal 0.7-1.3 x the default."""
    xs = [b.position[0] for b in scene.boxes] or [0.0]
    zs = [b.position[2] for b in scene.boxes] or [0.5]
    span = max(0.3, max(xs) - min(xs) + 0.3)
    aim = np.array([rng.uniform(min(xs), max(xs)), 0.0, rng.uniform(min(zs), max(zs) + 0.05)])
    base = default_camera()
    f = float(rng.uniform(0.7, 1.3)) * base.fx
    w, h = (480, 640) if rng.random() < 0.3 else (640, 480)
    dist = float(np.clip(rng.uniform(0.45, 1.4) * span * f / w, 0.9, 3.2))
    pos = np.array([aim[0] + rng.uniform(-1.0, 1.0) * min(1.2, 0.5 * dist), -dist,
                    float(np.clip(aim[2] + rng.uniform(-1.0, 1.0) * 0.6 * dist, 0.2, 2.6))])
    zax = (aim - pos) / np.linalg.norm(aim - pos)
    xax = np.cross(zax, [0.0, 0.0, 1.0])
    xax /= np.linalg.norm(xax)
    roll = math.radians(float(rng.uniform(-5, 5)))
    r = np.stack([xax, np.cross(zax, xax), zax], axis=1) @ _rot_z(roll)
    return Camera(w, h, f, f, (w - 1) / 2, (h - 1) / 2, base.depth_scale,
                  tuple(float(v) for v in pos), tuple(float(v) for v in matrix_to_quat(r)))  # type: ignore[arg-type]


def _tape(img: np.ndarray, rng: np.random.Generator) -> None:
    """1-3 bands of tape across the whole face, 4-25 % of its side wide, anywhere along it,
    vertical or horizontal (a cross when both): opaque coloured tape or clear tape (a glossy,
    slightly lighter band with darker edges)."""
    s = img.shape[0]
    for _ in range(int(rng.integers(1, 4))):
        wd = max(2, int(rng.uniform(0.04, 0.25) * s))
        a = int(rng.uniform(0.0, 1.0) * (s - wd))
        band = np.s_[:, a:a + wd] if rng.random() < 0.5 else np.s_[a:a + wd, :]
        if rng.random() < 0.6:
            tape = np.asarray(TAPE_RGB[rng.integers(len(TAPE_RGB))], np.float32) * rng.uniform(0.85, 1.15)
            img[band] = img[band] * rng.uniform(0.05, 0.35) + tape * 0.8
        else:
            img[band] = img[band] * rng.uniform(1.05, 1.35) + rng.uniform(5, 30)
        edge = max(1, wd // 8)
        if band[1] == slice(None):
            img[a:a + edge] *= 0.8
            img[a + wd - edge:a + wd] *= 0.8
        else:
            img[:, a:a + edge] *= 0.8
            img[:, a + wd - edge:a + wd] *= 0.8


def _stickers(img: np.ndarray, rng: np.random.Generator) -> None:
    """0-4 stickers, 10-45 % of the face's side each way, anywhere, a third of them running
    to a border of the face: white or yellow paper with a barcode and lines of text."""
    s = img.shape[0]
    for _ in range(int(rng.integers(0, 5))):
        lw, lh = int(rng.uniform(0.1, 0.45) * s), int(rng.uniform(0.1, 0.45) * s)
        x0, y0 = int(rng.integers(0, s - lw)), int(rng.integers(0, s - lh))
        if rng.random() < 0.33:
            x0 = 0 if rng.random() < 0.5 else s - lw
        if rng.random() < 0.33:
            y0 = 0 if rng.random() < 0.5 else s - lh
        paper = np.array([245, 245, 240] if rng.random() < 0.75 else [240, 220, 120], np.float32)
        img[y0:y0 + lh, x0:x0 + lw] = paper * rng.uniform(0.85, 1.0)
        ink = np.asarray(INK_RGB[rng.integers(len(INK_RGB))], np.float32)
        if rng.random() < 0.6:
            bars = np.nonzero(rng.random(max(1, lw - 6)) < 0.45)[0] + x0 + 3
            img[y0 + 3:y0 + max(4, lh // 2), bars] = ink
        for k in range(int(rng.integers(1, 5))):
            ty = y0 + lh - 4 - max(3, lh // 8) * k
            if ty <= y0 + 2:
                break
            img[ty:ty + max(1, lh // 20), x0 + 3:x0 + 3 + int(rng.uniform(0.3, 0.9) * (lw - 6))] = ink


def _shadow(img: np.ndarray, rng: np.random.Generator) -> None:
    """A hard shadow edge: the face on one side of a random straight line darkened."""
    s = img.shape[0]
    yy, xx = np.mgrid[0:s, 0:s].astype(np.float32) / s
    a = float(rng.uniform(0, 2 * math.pi))
    side = (xx - 0.5) * math.cos(a) + (yy - 0.5) * math.sin(a) > float(rng.uniform(-0.35, 0.35))
    img[side] *= float(rng.uniform(0.4, 0.8))


def taped_variant(tex: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """`_variant` of a group print with this carton's own tape (80 %), stickers and maybe a
    shadow edge (30 %) on top: what cuts a real face into pieces that are still one carton."""
    img = _variant(tex, rng).astype(np.float32)
    if rng.random() < 0.8:
        _tape(img, rng)
    _stickers(img, rng)
    if rng.random() < 0.3:
        _shadow(img, rng)
    return np.clip(img, 0, 255).astype(np.uint8)


def wall_example(seed: int, taped: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """(RGB uint8 HxWx3, front-face instance labels uint16) of wall training frame `seed`;
    `taped`: each carton's face cut by tape, stickers and shadows (`taped_variant`)."""
    rng = np.random.default_rng(seed + 2_000_003)
    scene, groups = wall_scene(rng)
    cam = wall_camera(rng, scene)
    prints = [_group_texture(rng) for _ in range(max(groups, default=0) + 1)]
    vary = taped_variant if taped else _variant
    per_box = [vary(prints[g], rng) for g in groups]
    cap = render(scene, cam, seed=seed, looks="printed", varied_light=bool(rng.random() < 0.6), textures=per_box)
    labels = np.zeros(cap.shape, np.uint16)
    for k, m in enumerate(front_face_masks(scene, cap).values(), start=1):
        labels[m] = k
    return cap.rgb, labels


def taped_wall_example(seed: int) -> tuple[np.ndarray, np.ndarray]:
    """A fourth-round frame (seeds >= `TAPED_SEED0`): `wall_example` with taped faces."""
    return wall_example(seed, taped=True)
