"""Tiny numpy ray caster for perception tests that must not depend on PyBullet.

Boxes are oriented cuboids; the shelf is a floor (z=0), a back wall (y=depth)
and side walls. Returns a `Capture` with exact depth and ground-truth masks.
"""
from __future__ import annotations

import numpy as np

from shelfpick.perception.capture import Capture
from shelfpick.perception.geometry import pixel_rays, pose_matrix
from shelfpick.perception.scene import Box, Camera, Scene, Shelf, quat_to_matrix

SMALL_CAMERA = Camera(320, 240, 300.0, 300.0, 160.0, 120.0, 0.001, (0.0, -1.0, 0.35),
                      (0.7071067811865476, -0.7071067811865476, 0.0, 0.0))

COLOURS = [(170, 120, 70), (200, 160, 110), (140, 95, 55), (215, 185, 140), (120, 80, 45),
           (185, 140, 90), (160, 130, 100), (205, 150, 80), (150, 110, 85), (190, 170, 120)]


def cast(scene: Scene, camera: Camera = SMALL_CAMERA, noise: float = 0.0, seed: int = 0,
         tape: bool = False) -> Capture:
    h, w = camera.height, camera.width
    vs, us = np.mgrid[0:h, 0:w]
    rot, t = pose_matrix(camera)
    dirs = pixel_rays(camera, us.ravel(), vs.ravel()) @ rot.T      # shelf frame, camera z = 1
    best = np.full(h * w, np.inf)
    label = np.zeros(h * w, np.uint16)
    face = np.zeros(h * w, np.int8)      # 0 shelf, 1 front, 2 top/other
    shelf: Shelf = scene.shelf
    # shelf: floor, back wall, side walls
    for axis, value in ((2, 0.0), (1, shelf.depth), (0, -shelf.width / 2), (0, shelf.width / 2)):
        with np.errstate(divide="ignore", invalid="ignore"):
            s = (value - t[axis]) / dirs[:, axis]
        s[~np.isfinite(s) | (s <= 0)] = np.inf
        best = np.minimum(best, s)
    for k, box in enumerate(scene.boxes, start=1):
        r = np.asarray(quat_to_matrix(box.orientation))
        o = r.T @ (t - np.asarray(box.position))
        d = dirs @ r
        half = np.asarray(box.size) / 2
        with np.errstate(divide="ignore", invalid="ignore"):
            t1 = (-half - o) / d
            t2 = (half - o) / d
        lo = np.minimum(t1, t2)
        hi = np.maximum(t1, t2)
        lo = np.where(np.isnan(lo), -np.inf, lo)
        hi = np.where(np.isnan(hi), np.inf, hi)
        tmin = lo.max(axis=1)
        tmax = hi.min(axis=1)
        hit = (tmax >= tmin) & (tmin > 0) & (tmin < best)
        best[hit] = tmin[hit]
        label[hit] = k
        entry_axis = lo.argmax(axis=1)
        front = (entry_axis == 1) & (d[:, 1] > 0)
        face[hit] = np.where(front[hit], 1, 2)
    depth = np.where(np.isfinite(best), best, 0.0).astype(np.float32).reshape(h, w)
    rng = np.random.default_rng(seed)
    if noise > 0:
        depth = depth + (rng.normal(0, noise, depth.shape) * depth ** 2).astype(np.float32)
    rgb = np.full((h * w, 3), 90, np.uint8)
    for k in range(1, len(scene.boxes) + 1):
        col = np.asarray(COLOURS[(k - 1) % len(COLOURS)])
        rgb[(label == k) & (face == 1)] = col
        rgb[(label == k) & (face == 2)] = (col * 0.75).astype(np.uint8)
    rgb = rgb.reshape(h, w, 3)
    lab = label.reshape(h, w)
    if tape:  # a darker vertical band down the middle of each front face, 15% of its width
        # (packing tape is ~5 cm on 20-60 cm faces; a 1-2 px dark line is what a seam between
        # two flush boxes looks like, and the segmenter keeps those apart on purpose)
        for k in range(1, len(scene.boxes) + 1):
            ys, xs = np.nonzero(lab == k)
            if len(xs):
                cx = int(np.median(xs))
                half = max(3, int(0.075 * (xs.max() - xs.min())))
                sel = (lab == k) & (np.abs(np.arange(w)[None, :] - cx) <= half)
                rgb[sel] = (rgb[sel] * 0.6).astype(np.uint8)
    labels = {k: b.id for k, b in enumerate(scene.boxes, start=1)}
    return Capture(rgb, depth, camera, lab, labels)


def box(bid: str, x: float, z_bottom: float, w: float, h: float, d: float = 0.2,
        front: float = 0.02, quat=(1.0, 0.0, 0.0, 0.0)) -> Box:
    return Box(bid, (w, d, h), (x, front + d / 2, z_bottom + h / 2), quat)
