"""Synthetic RGB-D captures of a scene: PyBullet's TinyRenderer, headless.

This is the built-in demo source and the segmenter's training and test data,
so two things matter: the geometry must agree exactly with the pinhole model
that perception back-projects with (the projection matrix is built from the
Camera intrinsics, not from a field of view), and the looks must vary like a
warehouse (cardboard colours, tape, labels, shelf paint, lighting, a
depth-sensor noise model). Ground-truth instance masks come from PyBullet's
segmentation buffer.
"""
from __future__ import annotations

import math
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from shelfpick.perception.capture import Capture
from shelfpick.perception.cardboard import BACKGROUND_RGB, SHELF_RGB, box_texture, plain_box_texture, plain_texture, write_png
from shelfpick.perception.geometry import pose_matrix, project  # noqa: F401 - project is part of this module's API
from shelfpick.perception.scene import Camera, Scene, quat_to_matrix, wxyz_to_xyzw
from shelfpick.perception.stdio import quiet_stdio

NEAR, FAR = 0.05, 6.0          # clip planes, metres
MAX_RANGE = 4.0                # beyond this a D435 reports nothing useful
DEFAULT_PITCH_DEG = 20.0       # camera tilted down so the floor row of boxes is in view


def _rot_x(angle: float) -> tuple[float, float, float, float]:
    return (math.cos(angle / 2), math.sin(angle / 2), 0.0, 0.0)


def default_camera(pitch_deg: float = DEFAULT_PITCH_DEG) -> Camera:
    """A RealSense D435 colour stream at 640x480, 1.05 m in front of the shelf, 0.8 m up.

    OpenCV axes: looking along +y with x to the right, tilted `pitch_deg` down
    (at 0 it would see z 0.4-1.2 m only, and miss the boxes on the floor).
    """
    q = _rot_x(-math.radians(90.0 + pitch_deg))
    return Camera(width=640, height=480, fx=607.6, fy=606.7, cx=315.7, cy=249.5,
                  depth_scale=0.001, position=(0.0, -1.05, 0.80), orientation=q)


def gl_view_matrix(camera: Camera) -> list[float]:
    """World->OpenGL-eye matrix (column-major, 16 floats) for the camera pose."""
    r, t = pose_matrix(camera)
    world_to_cv = np.eye(4)
    world_to_cv[:3, :3] = r.T
    world_to_cv[:3, 3] = -r.T @ t
    cv_to_gl = np.diag([1.0, -1.0, -1.0, 1.0])
    return list((cv_to_gl @ world_to_cv).T.reshape(-1))


def gl_projection_matrix(camera: Camera, near: float = NEAR, far: float = FAR) -> list[float]:
    """OpenGL projection from pinhole intrinsics (column-major).

    TinyRenderer samples pixel column c at viewport x = c and image row r at
    viewport y = H - 1 - r; the offsets below make it sample OpenCV pixel
    centres (u = c, v = r), measured with thin plates to within ~0.1 px
    (tests/perception/test_render.py checks the edges).
    """
    w, h = camera.width, camera.height
    m = np.zeros((4, 4))
    m[0, 0] = 2 * camera.fx / w
    m[0, 2] = 1 - 2 * camera.cx / w
    m[1, 1] = 2 * camera.fy / h
    m[1, 2] = 2 * (camera.cy + 1.0) / h - 1
    m[2, 2] = -(far + near) / (far - near)
    m[2, 3] = -2 * far * near / (far - near)
    m[3, 2] = -1.0
    return list(m.T.reshape(-1))


def linearize_depth(buffer: np.ndarray, near: float = NEAR, far: float = FAR) -> np.ndarray:
    """OpenGL depth buffer in [0, 1] -> metric z along the optical axis."""
    d = np.asarray(buffer, np.float64)
    return (far * near / (far - (far - near) * d)).astype(np.float32)


@dataclass(frozen=True)
class DepthNoise:
    """A D4xx-like depth error model (see docs/segmentation.md)."""

    sigma_per_m2: float = 0.001     # std = sigma_per_m2 * z^2 (m): ~1.1 mm at 1.05 m
    edge_jump: float = 0.02         # a neighbour this much farther makes a depth edge (m)
    edge_hole_prob: float = 0.6     # chance an edge pixel (and its 1-px ring) reads 0
    dropout: float = 0.002          # fraction of isolated missing pixels
    blobs: int = 3                  # up to this many small missing patches (specular spots)

    def apply(self, z: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        import cv2

        out = z.astype(np.float32).copy()
        valid = out > 0
        out[valid] += (rng.standard_normal(int(valid.sum())) * self.sigma_per_m2 * out[valid] ** 2
                       ).astype(np.float32)
        zz = np.where(valid, z, np.float32(FAR))
        edge = np.zeros(z.shape, bool)
        for axis in (0, 1):
            jump = np.abs(np.diff(zz, axis=axis)) > self.edge_jump
            if axis == 0:
                edge[1:] |= jump
                edge[:-1] |= jump
            else:
                edge[:, 1:] |= jump
                edge[:, :-1] |= jump
        ring = cv2.dilate(edge.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        holes = ring & (rng.random(z.shape) < self.edge_hole_prob)
        holes |= rng.random(z.shape) < self.dropout
        h, w = z.shape
        blobs = np.zeros(z.shape, np.uint8)
        for _ in range(int(rng.integers(0, self.blobs + 1))):
            cy, cx = int(rng.integers(0, h)), int(rng.integers(0, w))
            ry, rx = int(rng.integers(2, 7)), int(rng.integers(2, 9))
            cv2.ellipse(blobs, (cx, cy), (rx, ry), 0, 0, 360, 1, -1)
        holes |= blobs.astype(bool)
        out[holes] = 0.0
        out[out < 0] = 0.0
        return out


def _cube_mesh() -> tuple[list, list, list, list]:
    """Unit cube (+-1) with 4 vertices per face so each face maps the whole texture upright."""
    faces = [((1, 0, 0), (0, 1, 0), (0, 0, 1)), ((-1, 0, 0), (0, -1, 0), (0, 0, 1)),
             ((0, 1, 0), (-1, 0, 0), (0, 0, 1)), ((0, -1, 0), (1, 0, 0), (0, 0, 1)),
             ((0, 0, 1), (1, 0, 0), (0, 1, 0)), ((0, 0, -1), (1, 0, 0), (0, -1, 0))]
    verts, normals, uvs, idx = [], [], [], []
    for n, u, v in faces:
        n_, u_, v_ = np.array(n), np.array(u), np.array(v)
        base = len(verts)
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            verts.append([float(c) for c in n_ + su * u_ + sv * v_])
            normals.append(list(map(float, n)))
            uvs.append([(su + 1) / 2, (sv + 1) / 2])
        idx += [base, base + 1, base + 2, base, base + 2, base + 3]
    return verts, normals, uvs, idx


_CUBE = _cube_mesh()


class _Builder:
    """Static visual bodies in one BulletClient (rendering only: no collision, no mass)."""

    def __init__(self, client, tmp: Path):
        self.c = client
        self.tmp = tmp
        self.n_tex = 0

    def texture(self, img: np.ndarray) -> int:
        path = write_png(self.tmp / f"t{self.n_tex}.png", img)
        self.n_tex += 1
        return self.c.loadTexture(str(path))

    def box(self, half: tuple[float, float, float], pos, quat_xyzw=(0, 0, 0, 1),
            rgba=(1, 1, 1, 1), texture: np.ndarray | None = None) -> int:
        import pybullet as p

        v, n, uv, idx = _CUBE
        vs = self.c.createVisualShape(p.GEOM_MESH, vertices=v, indices=idx, uvs=uv, normals=n,
                                      meshScale=[float(h) for h in half], rgbaColor=list(rgba))
        body = self.c.createMultiBody(baseMass=0, baseVisualShapeIndex=vs,
                                      basePosition=[float(x) for x in pos],
                                      baseOrientation=[float(x) for x in quat_xyzw])
        if texture is not None:
            self.c.changeVisualShape(body, -1, textureUniqueId=self.texture(texture))
        return body


def _build_shelf(b: _Builder, scene: Scene, rng: np.random.Generator) -> None:
    s = scene.shelf
    t = float(rng.uniform(0.015, 0.03))                       # board thickness
    shelf_rgb = SHELF_RGB[rng.integers(len(SHELF_RGB))]
    board = plain_texture(rng, shelf_rgb, grain=float(rng.uniform(0.5, 3)))
    back = plain_texture(rng, SHELF_RGB[rng.integers(len(SHELF_RGB))] if rng.random() < 0.4 else shelf_rgb,
                         grain=float(rng.uniform(0.5, 3)))
    lip = float(rng.uniform(0.0, 0.03))                        # board front edge a bit ahead of y=0
    yc = (s.depth - lip) / 2
    b.box((s.width / 2 + t, (s.depth + lip) / 2, t / 2), (0, yc, -t / 2), texture=board)        # floor
    b.box((s.width / 2 + t, (s.depth + lip) / 2, t / 2), (0, yc, s.height + t / 2), texture=board)  # top
    for sx in (-1, 1):                                                                          # sides
        b.box((t / 2, (s.depth + lip) / 2, s.height / 2 + t), (sx * (s.width / 2 + t / 2), yc, s.height / 2),
              texture=board)
    b.box((s.width / 2 + t, t / 2, s.height / 2 + t), (0, s.depth + t / 2, s.height / 2), texture=back)
    # the level below (its boxes are not part of the scene): a board and a dark gap
    below = float(rng.uniform(0.25, 0.45))
    b.box((s.width / 2 + t, (s.depth + lip) / 2, t / 2), (0, yc, -below), texture=board)
    b.box((s.width / 2 + t, t / 2, below / 2), (0, s.depth + t / 2, -below / 2), texture=back)
    # room: a floor and a wall behind, some distance away
    bg = plain_texture(rng, BACKGROUND_RGB[rng.integers(len(BACKGROUND_RGB))], grain=float(rng.uniform(1, 5)))
    wall_y = s.depth + float(rng.uniform(0.3, 1.5))
    b.box((4.0, 0.01, 3.0), (0, wall_y, 1.0), texture=bg)
    b.box((4.0, 3.0, 0.01), (0, 0, -float(rng.uniform(0.8, 1.2))),
          texture=plain_texture(rng, BACKGROUND_RGB[rng.integers(len(BACKGROUND_RGB))]))


LOOKS = ("printed", "plain", "mixed")


def render(scene: Scene, camera: Camera | None = None, seed: int = 0, noise: bool = True,
           front_only: bool = True, looks: str = "printed", varied_light: bool = False,
           textures: Sequence[np.ndarray] | None = None, light: dict | None = None) -> Capture:
    """Render `scene` into a Capture with ground-truth masks (labels 1..N, visible boxes only).

    Masks hold each box's visible FRONT face (its local -y face), the part
    perception measures; a camera above a box also sees its top, which
    `front_only=False` includes. A box with no visible (front) pixel gets no label.

    `seed` draws the looks (cardboard, tape, labels, shelf paint, lighting) and
    the noise; `noise=False` gives the exact z-depth and the clean colour image.
    `looks`: "printed" (tape, labels, print: what the rules were tuned on), "plain"
    (`cardboard.plain_box_texture`: no tape, no label) or "mixed" (each box either);
    `varied_light`: dimmer to brighter ambient light, harder shadows and a wider colour cast
    than the tuned renders. `textures`: one texture per box, in scene order, instead of drawn ones
    (cartons that share a print); what the seed draws after the boxes (the light, the noise) then
    differs from the same seed without them. `light`: getCameraImage light arguments that
    replace the drawn ones (drawn all the same, so the noise draws do not move), e.g. one hard
    directional light (`training/printed_shelves.py`). The defaults
    draw exactly what they drew before (same seed, same image).
    """
    if textures is not None and len(textures) != len(scene.boxes):
        raise ValueError(f"textures: expected one per box ({len(scene.boxes)}), got {len(textures)}")
    if looks not in LOOKS:
        raise ValueError(f"looks must be one of {LOOKS}, got {looks!r}")
    cam = camera or scene.camera or default_camera()
    rng = np.random.default_rng(seed)
    rgba, zbuf, seg, body_to_box = _snapshot(scene, cam, rng, looks, textures, varied_light, light)
    h, w = cam.height, cam.width
    rgb = np.asarray(rgba, np.uint8).reshape(h, w, 4)[:, :, :3].copy()
    z = linearize_depth(np.asarray(zbuf, np.float32).reshape(h, w))
    z[z > MAX_RANGE] = 0.0
    seg = np.asarray(seg, np.int64).reshape(h, w)

    masks, labels = _instance_masks(scene, cam, seg, z, body_to_box, front_only)

    if noise:
        rgb = _camera_look(rgb, rng)
        z = DepthNoise().apply(z, rng)
    return Capture(rgb, z, cam, masks, labels)


def _snapshot(scene: Scene, cam: Camera, rng: np.random.Generator, looks: str,
              textures: Sequence[np.ndarray] | None, varied_light: bool, light: dict | None) -> tuple:
    """(rgba, z-buffer, segmentation, body -> box id) of the shelf and its boxes built in a Bullet
    client of its own (closed before it returns), as the camera sees them; draws from `rng` in
    the order the seeds' images depend on: shelf, boxes, then the light."""
    with quiet_stdio():   # pybullet prints its build time on import and "argv[0]=" on connect
        import pybullet as p
        from pybullet_utils.bullet_client import BulletClient

        client = BulletClient(connection_mode=p.DIRECT)
    try:
        with tempfile.TemporaryDirectory(prefix="shelfpick-render-") as tmp:
            builder = _Builder(client, Path(tmp))
            _build_shelf(builder, scene, rng)
            body_to_box = _build_boxes(builder, scene, rng, looks, textures)
            _, _, rgba, zbuf, seg = client.getCameraImage(
                cam.width, cam.height, gl_view_matrix(cam), gl_projection_matrix(cam),
                renderer=p.ER_TINY_RENDERER, **{**_lighting(rng, varied_light), **(light or {})})
    finally:
        client.disconnect()
    return rgba, zbuf, seg, body_to_box


def _build_boxes(b: _Builder, scene: Scene, rng: np.random.Generator, looks: str,
                 textures: Sequence[np.ndarray] | None) -> dict[int, str]:
    """The scene's boxes, each with its drawn (or given) cardboard texture; body id -> box id.
    The look and the texture size are drawn for every box, given textures or not; a drawn
    texture draws more (so given textures move the draws that come after the boxes)."""
    body_to_box: dict[int, str] = {}
    for k, box in enumerate(scene.boxes):
        plain = looks == "plain" or (looks == "mixed" and rng.random() < 0.5)
        size = int(rng.choice([64, 96, 128]))
        tex = textures[k] if textures is not None else (plain_box_texture if plain else box_texture)(rng, size=size)
        body = b.box(tuple(x / 2 for x in box.size), box.position, wxyz_to_xyzw(box.orientation), texture=tex)
        body_to_box[body] = box.id
    return body_to_box


def _lighting(rng: np.random.Generator, varied: bool) -> dict:
    """getCameraImage light arguments; `varied` widens every range (the draws of the default
    ranges are unchanged, so old seeds render the same images)."""
    light_dir = [float(rng.uniform(-1.5, 1.5)), float(rng.uniform(-2.5, -0.5)), float(rng.uniform(1.0, 3.0))]
    warm = float(rng.uniform(-0.08, 0.08)) * (2.0 if varied else 1.0)
    shadow = int(rng.random() < (0.8 if varied else 0.6))
    amb = (0.2, 0.8) if varied else (0.35, 0.7)
    dif = (0.2, 0.8) if varied else (0.3, 0.65)
    spec = (0.0, 0.3) if varied else (0.0, 0.15)
    return {"lightDirection": light_dir, "lightColor": [1.0 + warm, 1.0, 1.0 - warm], "lightDistance": 3.0,
            "shadow": shadow, "lightAmbientCoeff": float(rng.uniform(*amb)),
            "lightDiffuseCoeff": float(rng.uniform(*dif)), "lightSpecularCoeff": float(rng.uniform(*spec))}


def _instance_masks(scene: Scene, cam: Camera, seg: np.ndarray, z: np.ndarray,
                    body_to_box: dict[int, str], front_only: bool,
                    tol: float = 0.003) -> tuple[np.ndarray, dict[int, str]]:
    """Label image from the segmentation buffer; with `front_only`, pixels whose exact
    back-projected point lies on the box's front face plane (within `tol` m)."""
    h, w = seg.shape
    masks = np.zeros((h, w), np.uint16)
    labels: dict[int, str] = {}
    r, t = pose_matrix(cam)
    for body, box_id in body_to_box.items():
        hit = seg == body
        if front_only and hit.any():
            box = scene.require(box_id)
            vs, us = np.nonzero(hit)
            zc = z[vs, us].astype(np.float64)
            pc = np.stack([(us - cam.cx) / cam.fx * zc, (vs - cam.cy) / cam.fy * zc, zc], axis=1)
            local = (pc @ r.T + t - np.asarray(box.position)) @ np.asarray(quat_to_matrix(box.orientation))
            on_front = np.abs(local[:, 1] + box.size[1] / 2) < tol
            hit = np.zeros_like(hit)
            hit[vs[on_front], us[on_front]] = True
        if hit.any():
            label = len(labels) + 1
            masks[hit] = label
            labels[label] = box_id
    return masks, labels


def _camera_look(rgb: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Exposure, white balance, sensor noise and a touch of blur, as a colour camera adds."""
    import cv2

    img = rgb.astype(np.float32)
    img *= rng.uniform(0.8, 1.15) * rng.uniform(0.94, 1.06, 3)
    img += rng.uniform(-12, 12)
    if rng.random() < 0.5:
        img = cv2.GaussianBlur(img, (3, 3), float(rng.uniform(0.3, 0.9)))
    img += rng.normal(0, rng.uniform(1.0, 4.0), img.shape).astype(np.float32)
    return np.clip(img, 0, 255).astype(np.uint8)


__all__ = ["default_camera", "render", "project", "DepthNoise", "gl_view_matrix",
           "gl_projection_matrix", "linearize_depth"]
