"""A pure-numpy ray caster of a shelf of oriented boxes: exact z-depth, surface normals, hit ids.

Written for issue 31 so that perception can be judged on frames whose geometry, camera and
shading share no code or assets with the training renderer (perception/render.py, cardboard.py,
training/scenes.py): no PyBullet, no OpenGL, no texture files. Every solid is an oriented box
(the shelf's boards are boxes too); a pixel's ray direction is scaled so that its parameter at a
hit IS the camera z-depth that depth images store.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

BOARD = 0.02          # shelf board thickness (m)


@dataclass(frozen=True)
class Cam:
    """Pinhole camera, OpenCV axes (x right, y down, z forward); `rot` takes camera to shelf frame."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    rot: tuple            # 3x3 as nested tuples
    pos: tuple            # (3,)

    def json(self, depth_scale: float = 0.001) -> dict:
        """The camera as a shelfpick.camera/1 document (scalar-first quaternion)."""
        return {"format": "shelfpick.camera/1", "width": self.width, "height": self.height,
                "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy, "depth_scale": depth_scale,
                "pose": {"position": [float(v) for v in self.pos], "orientation": quat_of(np.array(self.rot))}}

    def project(self, pts: np.ndarray) -> np.ndarray:
        """Pixel (u, v) of shelf-frame points (N, 3)."""
        pc = (np.asarray(pts, float) - np.array(self.pos)) @ np.array(self.rot)
        return np.stack([self.fx * pc[:, 0] / pc[:, 2] + self.cx, self.fy * pc[:, 1] / pc[:, 2] + self.cy], 1)


@dataclass(frozen=True)
class Solid:
    """An oriented box: centre, rotation (local -> shelf, columns are the local axes), half sizes."""

    centre: np.ndarray
    rot: np.ndarray
    half: np.ndarray
    label: int            # > 0 a carton (its mask label), 0 a board or background


def quat_of(m: np.ndarray) -> list[float]:
    """Scalar-first unit quaternion of a rotation matrix (w >= 0)."""
    w = math.sqrt(max(0.0, 1.0 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1.0 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1.0 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1.0 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    n = math.sqrt(w * w + x * x + y * y + z * z)
    return [w / n, x / n, y / n, z / n]


def rot_of(q) -> np.ndarray:
    """Rotation matrix of a scalar-first quaternion."""
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                     [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                     [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])


def solids(scene: dict) -> tuple[list[Solid], dict[int, str]]:
    """The scene's cartons (labels 1..n in scene order) and the shelf's boards; label -> box id."""
    out, labels = [], {}
    for i, b in enumerate(scene["boxes"], start=1):
        out.append(Solid(np.array(b["position"], float), rot_of(b["orientation"]),
                         np.array(b["size"], float) / 2, i))
        labels[i] = b["id"]
    s = scene["shelf"]
    w, d, h, t = s["width"], s["depth"], s["height"], BOARD
    eye = np.eye(3)
    for c, half in (((0, d / 2, -t / 2), (w / 2 + t, d / 2, t / 2)),            # floor
                    ((0, d / 2, h + t / 2), (w / 2 + t, d / 2, t / 2)),         # top
                    ((-w / 2 - t / 2, d / 2, h / 2), (t / 2, d / 2, h / 2 + t)),  # left side
                    ((w / 2 + t / 2, d / 2, h / 2), (t / 2, d / 2, h / 2 + t)),   # right side
                    ((0, d + t / 2, h / 2), (w / 2 + t, t / 2, h / 2 + t)),      # back
                    ((0, d / 2 + 2.0, -0.3 - t), (6.0, 6.0, 0.3)),              # the room's floor, below
                    ((0, d + 1.5, 1.0), (6.0, 0.05, 6.0))):                      # the room's wall, behind
        out.append(Solid(np.array(c, float), eye, np.array(half, float), 0))
    return out, labels


def pixel_dirs(cam: Cam) -> np.ndarray:
    """HxWx3 shelf-frame ray directions with camera-z component 1 (ray parameter = z-depth)."""
    vs, us = np.mgrid[0:cam.height, 0:cam.width].astype(np.float64)
    d = np.stack([(us - cam.cx) / cam.fx, (vs - cam.cy) / cam.fy, np.ones_like(us)], -1)
    return d @ np.array(cam.rot).T


def _near(origin: np.ndarray, dirs: np.ndarray, s: Solid) -> np.ndarray:
    """Rays that pass within the solid's bounding sphere (a cheap test before the exact one)."""
    w = s.centre - origin
    dd = np.einsum("ij,ij->i", dirs, dirs)
    if origin.ndim == 1:
        wd = dirs @ w
        ww = float(w @ w)
    else:
        wd = np.einsum("ij,ij->i", dirs, w)
        ww = np.einsum("ij,ij->i", w, w)
    r2 = float(s.half @ s.half) * 1.0001 + 1e-9
    return (ww - wd * wd / dd < r2) & ((wd > 0) | (ww < r2))


def _slab(origin: np.ndarray, dirs: np.ndarray, s: Solid) -> tuple[np.ndarray, np.ndarray]:
    """(entry t, entry axis*2+side) of rays (N,3 origins or one) into a solid; inf where missed."""
    o = (origin - s.centre) @ s.rot
    d = dirs @ s.rot
    d = np.where(np.abs(d) < 1e-12, 1e-12, d)
    t1, t2 = (-s.half - o) / d, (s.half - o) / d
    tn, tf = np.minimum(t1, t2), np.maximum(t1, t2)
    axis = np.argmax(tn, axis=-1)
    t_in, t_out = tn.max(-1), tf.min(-1)
    hit = (t_out >= t_in) & (t_out > 1e-6) & (t_in > 1e-6)
    t = np.where(hit, t_in, np.inf)
    side = (d[np.arange(len(d)), axis] > 0).astype(int)   # 1: entered by the - face
    return t, axis * 2 + side


def cast(cam: Cam, parts: list[Solid]) -> dict[str, np.ndarray]:
    """Per pixel: z-depth `t`, solid index `idx` (-1 none), shelf-frame `normal` and `point`, and the
    hit's coordinates in its solid's frame `local` (for printing on faces)."""
    dirs = pixel_dirs(cam).reshape(-1, 3)
    origin = np.array(cam.pos, float)
    best = np.full(len(dirs), np.inf)
    idx = np.full(len(dirs), -1)
    face = np.zeros(len(dirs), int)
    for i, s in enumerate(parts):
        near = np.flatnonzero(_near(origin, dirs, s))
        t, f = _slab(origin, dirs[near], s)
        closer = t < best[near]
        sel = near[closer]
        best[sel], idx[sel], face[sel] = t[closer], i, f[closer]
    point = origin + dirs * np.where(np.isfinite(best), best, 0.0)[:, None]
    normal = np.zeros_like(dirs)
    local = np.zeros_like(dirs)
    for i, s in enumerate(parts):
        m = idx == i
        if not m.any():
            continue
        n_loc = np.zeros((int(m.sum()), 3))
        ax, side = face[m] // 2, face[m] % 2
        n_loc[np.arange(len(ax)), ax] = np.where(side == 1, -1.0, 1.0)
        normal[m] = n_loc @ s.rot.T
        local[m] = (point[m] - s.centre) @ s.rot
    h, w = cam.height, cam.width
    return {"t": best.reshape(h, w), "idx": idx.reshape(h, w), "normal": normal.reshape(h, w, 3),
            "point": point.reshape(h, w, 3), "local": local.reshape(h, w, 3), "face": face.reshape(h, w)}


def blocked(points: np.ndarray, toward: np.ndarray, parts: list[Solid], *, directional: bool,
            skip_far: float = 50.0, only: np.ndarray | None = None) -> np.ndarray:
    """Whether each point (N,3) is hidden from a light: `toward` a direction (directional) or a
    point (a second camera's centre). Used for hard shadows and for stereo occlusion holes.
    `only`: the points worth testing (the rest come back False)."""
    todo = np.flatnonzero(only) if only is not None else np.arange(len(points))
    pts = points[todo]
    if directional:
        dirs = np.ascontiguousarray(np.broadcast_to(toward, pts.shape))
        reach = skip_far
    else:
        dirs = toward - pts
        reach = 1.0
    hit = np.zeros(len(pts), bool)
    for s in parts:
        near = np.flatnonzero(_near(pts, dirs, s) & ~hit)
        t, _ = _slab(pts[near], dirs[near], s)
        hit[near] |= (t > 1e-4) & (t < reach)
    out = np.zeros(len(points), bool)
    out[todo] = hit
    return out


def look_at(width: int, height: int, fx: float, fy: float, pos, target) -> Cam:
    """A camera at `pos` looking at `target` with the image's x axis level (no roll)."""
    pos, target = np.asarray(pos, float), np.asarray(target, float)
    z = target - pos
    z /= np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    rot = np.stack([x, y, z], 1)
    return Cam(width, height, fx, fy, (width - 1) / 2, (height - 1) / 2,
               tuple(map(tuple, rot)), tuple(pos))


def frame_boxes(scene: dict, width: int, height: int, fx: float, fy: float, rng: np.random.Generator,
                margin_px: float = 30.0, height_m: float = 0.85) -> Cam:
    """A camera in front of the shelf (seeded jitter in x, height and aim) that sees every carton's
    front corners `margin_px` inside the image: backs off along -y until they fit."""
    corners = []
    for b in scene["boxes"]:
        r, half = rot_of(b["orientation"]), np.array(b["size"]) / 2
        for sx in (-1, 1):
            for sz in (-1, 1):
                corners.append(np.array(b["position"]) + r @ (half * np.array([sx, -1, sz])))
    pts = np.array(corners)
    lo, hi = pts.min(0), pts.max(0)
    cx = float(rng.uniform(-0.08, 0.08))
    cz = float(np.clip(height_m + rng.uniform(-0.1, 0.1), 0.5, 1.2))
    aim = np.array([(lo[0] + hi[0]) / 2 + rng.uniform(-0.03, 0.03), lo[1], (lo[2] + hi[2]) / 2])
    y = float(lo[1]) - 0.9
    for _ in range(200):
        cam = look_at(width, height, fx, fy, (cx, y, cz), aim)
        uv = cam.project(pts)
        if (uv[:, 0].min() > margin_px and uv[:, 0].max() < width - margin_px
                and uv[:, 1].min() > margin_px and uv[:, 1].max() < height - margin_px):
            return cam
        y -= 0.02
    raise ValueError("no camera up to 4 m back frames every carton front")


def colour_to_uint8(img: np.ndarray) -> np.ndarray:
    """Linear [0, 1] light to 8-bit with a plain 2.2 gamma."""
    return (np.clip(img, 0.0, 1.0) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)
