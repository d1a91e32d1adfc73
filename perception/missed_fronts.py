"""Box fronts the segmenter missed, found in the matter no perceived box explains (issue 31).

The depth image says where matter is, whatever the segmenter says. A region of unexplained matter
whose seen surface is one flat rectangle facing the camera, box-sized and clear of every perceived
front, is a box front the segmenter missed: on the tuning look `labels`, a cube flush beside
cartons of the same print that no network instance covered. Planning on it as unexplained matter
keeps the plan unsafe but still pulls the box under it as if nothing rested there. Such a region is
perceived as a box instead, with a note saying so; every other region stays unexplained matter.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from shelfpick.perception.faces import FrontFace, measure_front
from shelfpick.perception.geometry import point_map
from shelfpick.perception.scene import Box, Camera, Shelf

MIN_FILL = 0.85       # the region fills its min-area rectangle at least this much (a face, not a band or an L)
MIN_SIDE = 0.10       # each side of the face at least this (m): the repeat cuts' smallest front
MIN_FACING = 0.80     # cos of the angle between its plane's normal and shelf +y (the depth gate's)
MIN_ON_PLANE = 0.85   # share of its points within the depth gate's 12 mm of that plane: one face, not two
MAX_OVERLAP = 0.10    # at most this share of it lies within a perceived box's front, seen from the front


@dataclass(frozen=True, eq=False)
class MissedFront:
    """An unexplained region taken for a box front: its id, pixels and measured face."""

    region: str
    mask: np.ndarray
    face: FrontFace
    fill: float

    @property
    def note(self) -> str:
        return (f"{self.region}: matter no mask covered is one flat {self.face.size_cm} front facing the camera "
                f"(fills {self.fill:.2f} of its rectangle): perceived as a box the segmenter missed")


def _front_overlap(face: FrontFace, boxes: Sequence[Box]) -> float:
    """The largest share of the face's rectangle (x, z) that lies within one box's front rectangle."""
    x, _, z = face.center
    fx0, fx1, fz0, fz1 = x - face.width / 2, x + face.width / 2, z - face.height / 2, z + face.height / 2
    area = max(face.width * face.height, 1e-9)
    best = 0.0
    for b in boxes:
        bx0, bx1 = b.position[0] - b.size[0] / 2, b.position[0] + b.size[0] / 2
        bz0, bz1 = b.position[2] - b.size[2] / 2, b.position[2] + b.size[2] / 2
        w, h = min(fx1, bx1) - max(fx0, bx0), min(fz1, bz1) - max(fz0, bz0)
        if w > 0 and h > 0:
            best = max(best, w * h / area)
    return best


def missed_fronts(region_ids: Sequence[str], labels: np.ndarray, boxes: Sequence[Box], depth: np.ndarray,
                  camera: Camera, shelf: Shelf) -> list[MissedFront]:
    """The regions (label k+1 = region_ids[k]) that measure as a box front no perceived box covers."""
    from shelfpick.perception.boxes import not_a_face, not_a_front
    from shelfpick.perception.repairs.merged import rect_fill

    out = []
    for k, rid in enumerate(region_ids):
        sel = labels == k + 1
        q = measure_front(sel, depth, camera)
        if q is None or not_a_front(q, shelf) or not_a_face(q, sel) or min(q.width, q.height) < MIN_SIDE:
            continue
        fill = rect_fill(sel)
        if fill < MIN_FILL or _front_overlap(q, boxes) > MAX_OVERLAP or not _one_facing_plane(sel, depth, camera, shelf):
            continue
        out.append(MissedFront(rid, sel, q, fill))
    return out


def _one_facing_plane(sel: np.ndarray, depth: np.ndarray, camera: Camera, shelf: Shelf) -> bool:
    """Most of the region's points lie on one plane (RANSAC, seeded: the depth gate's) that faces the
    camera: a box front, not the two faces of a turned carton (whose mean plane may face it)."""
    from shelfpick.perception.face_gate import GateConfig, evidence, inside_shelf

    cfg = GateConfig()
    d = np.asarray(depth, np.float32)
    valid = d > 0
    pts = point_map(camera, np.where(valid, d, 0.0).astype(np.float32))
    ev = evidence(sel, pts, valid, inside_shelf(pts, shelf, 0.0), cfg, np.random.default_rng(0))
    return ev.normal_cos is not None and ev.normal_cos >= MIN_FACING and (ev.on_plane or 0.0) >= MIN_ON_PLANE
