"""Which of an RGB segmenter's instances the depth confirms as box front faces.

Why: a network that sees colour only finds carton-like regions wherever they are: the floor
beside a pallet, a wall behind a shelf, the side of a machine. In an RGB-D capture the depth
says whether a region can be a front face: most of its points lie inside the shelf volume
(in front of the back wall), and its largest plane faces the camera the way a front face
does (shelf +y within the depth-and-edge rules' facing angle). The depth-and-edge segmenter
applies the same two tests pixel by pixel before it cuts faces; here they judge whole
instances, so a face with noisy depth or a strip of something else at its edge stays one
face. The dominant plane is found by RANSAC (seeded, so repeatable), not least squares: an
instance that spills over a box's edge onto the pallet is still mostly its front face.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shelfpick.perception.geometry import point_map
from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.crop import box_nonzero
from shelfpick.perception.scene import Camera, Shelf


@dataclass(frozen=True)
class GateConfig:
    """The tests' settings; the defaults are the depth-and-edge rules' own (`DepthEdgeConfig`:
    `facing_cos`, `jump_abs` as the plane tolerance, `wall_margin`), not fitted here."""

    min_inside: float = 0.5       # share of an instance's depth points inside the shelf volume
    facing_cos: float = 0.80      # cos of the largest angle between its plane's normal and shelf +y
    plane_tol: float = 0.012      # m: a point this close to a plane lies on it
    wall_margin: float = 0.012    # m: points this close to the back wall are the shelf
    min_points: int = 30          # fewer depth points inside the shelf: no plane test
    min_on_plane: float = 0.5     # `plausible_faces`: share of the points on the dominant plane
    sample: int = 2000            # points a plane is fitted to (a sample of the instance)
    tries: int = 100              # RANSAC draws per instance


@dataclass(frozen=True)
class FaceEvidence:
    """What the depth says about one instance; `normal_cos` is None without enough points."""

    depth_points: int
    inside_share: float
    normal_cos: float | None
    on_plane: float | None

    def is_face(self, cfg: GateConfig) -> bool:
        if self.depth_points == 0:
            return True             # no depth to judge by: left to the pipeline's cleaning
        if self.inside_share < cfg.min_inside:
            return False
        return self.normal_cos is None or self.normal_cos >= cfg.facing_cos


def inside_shelf(points: np.ndarray, shelf: Shelf, wall_margin: float) -> np.ndarray:
    """HxW: shelf-frame points inside the shelf volume and more than `wall_margin` in front of
    its back wall (as `segment_depth` keeps them)."""
    return inside_shelf_xyz(points[..., 0], points[..., 1], points[..., 2], shelf, wall_margin)


def inside_shelf_xyz(x: np.ndarray, y: np.ndarray, z: np.ndarray, shelf: Shelf, wall_margin: float) -> np.ndarray:
    """`inside_shelf` of points given as their x, y and z images (no HxWx3 array made for it)."""
    return (y < shelf.depth - wall_margin) & (np.abs(x) < shelf.width / 2 - 0.003) & (z > 0.005) \
        & (z < shelf.height - 0.003)


def dominant_plane(pts: np.ndarray, tol: float, tries: int,
                   rng: np.random.Generator) -> tuple[np.ndarray, float]:
    """(unit normal, share of points within `tol`) of the plane through the most points
    (RANSAC on three-point draws, all scored at once, refined by least squares on its inliers)."""
    s = pts[rng.integers(0, len(pts), size=(tries, 3))]           # tries x 3 points x xyz
    n = np.cross(s[:, 1] - s[:, 0], s[:, 2] - s[:, 0])
    nn = np.linalg.norm(n, axis=1)
    ok = nn > 1e-12
    if not ok.any():
        return np.array([0.0, 0.0, 1.0]), 0.0
    n, o = n[ok] / nn[ok, None], s[ok, 0]
    dist = pts @ n.T                                                # points x draws, then
    dist -= np.einsum("ij,ij->i", o, n)                             # their distances, in place
    np.abs(dist, out=dist)
    best = int(np.argmax((dist < tol).view(np.uint8).sum(axis=0)))  # inliers per draw
    inl = dist[:, best] < tol
    normal = n[best]
    if count(inl) >= 3:
        on = np.compress(inl, pts, axis=0)                          # pts[inl], 4x faster for rows
        c = on.mean(axis=0)
        normal = np.linalg.svd(on - c, full_matrices=False)[2][2]
    return normal, float(inl.mean())


def evidence(mask: np.ndarray, points: np.ndarray, valid: np.ndarray, inside: np.ndarray,
             cfg: GateConfig, rng: np.random.Generator) -> FaceEvidence:
    """The depth's evidence on one instance (`points`: HxWx3 shelf frame)."""
    ys, xs = box_nonzero(mask)
    have = valid[ys, xs]
    n = int(have.sum())
    if n == 0:
        return FaceEvidence(0, 0.0, None, None)
    sel = have & inside[ys, xs]
    k = int(sel.sum())
    if k < cfg.min_points:
        return FaceEvidence(n, k / n, None, None)
    step = max(1, k // cfg.sample)
    pts = points[ys[sel][::step], xs[sel][::step]].astype(np.float64)
    normal, share = dominant_plane(pts, cfg.plane_tol, cfg.tries, rng)
    return FaceEvidence(n, k / n, abs(float(normal[1])), share)


def _judged(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, shelf: Shelf, cfg: GateConfig,
            seed: int) -> list[tuple[np.ndarray, FaceEvidence]]:
    """Each mask with the depth's evidence on it (the frame's points computed once)."""
    if not masks:
        return []
    points = point_map(camera, depth)
    valid = np.isfinite(depth) & (depth > 0)
    inside = inside_shelf(points, shelf, cfg.wall_margin)
    return [(m, evidence(m, points, valid, inside, cfg, np.random.default_rng(seed))) for m in masks]


def keep_faces(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, shelf: Shelf,
               cfg: GateConfig = GateConfig(), seed: int = 0) -> list[np.ndarray]:
    """The instances the depth confirms as front faces (see the module docstring), in order."""
    return [m for m, ev in _judged(masks, depth, camera, shelf, cfg, seed) if ev.is_face(cfg)]


def plausible_faces(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, shelf: Shelf,
                    cfg: GateConfig = GateConfig(), seed: int = 0) -> list[np.ndarray]:
    """The masks the depth makes front faces on its own: the gate's tests with evidence
    required (enough points inside the shelf for a plane) and most points (`min_on_plane`) on
    that plane. Why: for a region the RGB network saw nothing in, there is no colour evidence
    of a face to fall back on, so the depth alone must show a flat facing surface."""
    return [m for m, ev in _judged(masks, depth, camera, shelf, cfg, seed)
            if ev.normal_cos is not None and ev.is_face(cfg) and (ev.on_plane or 0.0) >= cfg.min_on_plane]
