"""Ground truth for the perception benchmark: the visible part of each true front face.

The renderer's instance masks cover every visible face of a box (its top too,
seen from a camera above it); perception measures front faces. The fair
reference is therefore the pixels whose ray meets the box's front rectangle
and whose rendered instance is that box.
"""
from __future__ import annotations

import numpy as np

from shelfpick.perception.capture import Capture
from shelfpick.perception.geometry import ray_plane
from shelfpick.perception.scene import Scene, quat_to_matrix


def front_face_masks(scene: Scene, capture: Capture) -> dict[str, np.ndarray]:
    """Box id -> HxW bool mask of its visible front face (needs the capture's true masks)."""
    if capture.masks is None:
        raise ValueError("the capture has no ground-truth masks")
    cam = capture.camera
    h, w = capture.shape
    vs, us = np.mgrid[0:h, 0:w]
    us, vs = us.ravel().astype(np.float64), vs.ravel().astype(np.float64)
    by_id = {v: k for k, v in capture.labels.items()}
    out: dict[str, np.ndarray] = {}
    for b in scene.boxes:
        if b.id not in by_id:
            continue
        inst = capture.masks == by_id[b.id]
        if not inst.any():
            continue
        r = np.asarray(quat_to_matrix(b.orientation))
        n = r[:, 1]
        fc = np.asarray(b.front_center)
        ys, xs = np.nonzero(inst)
        hit = ray_plane(cam, xs.astype(np.float64), ys.astype(np.float64), fc, n)
        loc = (hit - fc) @ r
        inside = (np.abs(loc[:, 0]) <= b.size[0] / 2) & (np.abs(loc[:, 2]) <= b.size[2] / 2)
        m = np.zeros((h, w), bool)
        m[ys[inside], xs[inside]] = True
        if m.sum() >= 20:
            out[b.id] = m
    return out
