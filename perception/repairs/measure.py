"""What every repair step works with: the capture (`RepairContext`), a mask's measured face
(`Measured`, memoised per call in a `FaceCache`), and the masks next to a mask (on a face's plane:
`plane_dist`, here because `neighbour_pieces` needs it and `perception.repairs.planes` needs
`RepairContext`)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING

import cv2
import numpy as np

from shelfpick.perception.faces import FrontFace, face_axes, measure_front
from shelfpick.perception.geometry import backproject
from shelfpick.perception.masks import border_sides
from shelfpick.perception.repairs.crop import Near, box_nonzero
from shelfpick.perception.scene import Camera

if TYPE_CHECKING:
    from shelfpick.perception.catalogue import Catalogue


# `RepairContext.lab` of an 8-bit image by lookup: L as it is, a and b as (v - 128) * 2 in float32
_LAB_VALUES = np.arange(256, dtype=np.float32)
_LAB_TABLE = np.stack([_LAB_VALUES, (_LAB_VALUES - 128) * 2, (_LAB_VALUES - 128) * 2], axis=1).reshape(1, 256, 3)


@dataclass(frozen=True, eq=False)
class Measured:
    """A mask, its measured front face and that face's error to the closest type face (m)."""

    mask: np.ndarray
    face: FrontFace
    err: float


class FaceCache:
    """Measured faces by mask object, and masks' distances to faces' planes (`plane_dist`) by
    face and mask object, for one `apply_catalogue` call (the steps measure the same masks, and
    test them against the same neighbours' planes, again and again; no step changes a mask in
    place once it has handed it on). It holds each mask and face, so an id is not reused while
    the cache lives; it dies with the call."""

    def __init__(self) -> None:
        self._hits: dict[int, tuple[np.ndarray, Measured | None]] = {}
        self._dists: dict[tuple[int, int], tuple[FrontFace, np.ndarray, float]] = {}

    def dist(self, face: FrontFace, mask: np.ndarray) -> float | None:
        """The cached `plane_dist` of the mask to the face's plane, None if not cached."""
        hit = self._dists.get((id(face), id(mask)))
        return hit[2] if hit is not None and hit[0] is face and hit[1] is mask else None

    def put_dist(self, face: FrontFace, mask: np.ndarray, d: float) -> None:
        self._dists[(id(face), id(mask))] = (face, mask, d)

    def get(self, mask: np.ndarray) -> tuple[bool, Measured | None]:
        hit = self._hits.get(id(mask))
        if hit is not None and hit[0] is mask:
            return True, hit[1]
        return False, None

    def put(self, mask: np.ndarray, measured: Measured | None) -> None:
        self._hits[id(mask)] = (mask, measured)


@dataclass(frozen=True, eq=False)
class RepairContext:
    """The capture the masks come from and the catalogue that explains them. `cache`: the
    measured faces of the masks the steps keep (None: measure every time)."""

    depth: np.ndarray
    camera: Camera
    cat: "Catalogue"
    rgb: np.ndarray | None = None
    cache: FaceCache | None = field(default=None, repr=False)

    def measure(self, mask: np.ndarray) -> Measured | None:
        """The measured face of a mask (memoised in `cache`)."""
        if self.cache is not None:
            found, hit = self.cache.get(mask)
            if found:
                return hit
        out = self.measure_once(mask)
        if self.cache is not None:
            self.cache.put(mask, out)
        return out

    def measure_once(self, mask: np.ndarray) -> Measured | None:
        """The measured face of a mask that is only looked at once (a candidate union): not cached."""
        f = measure_front(mask, self.depth, self.camera)
        return None if f is None else Measured(mask, f, self.cat.error(f.width, f.height))

    @cached_property
    def lab(self) -> np.ndarray | None:
        """The colour image in CIELAB, a and b doubled (seams in hue count as much as in light)."""
        if self.rgb is None:
            return None
        lab = cv2.cvtColor(self.rgb, cv2.COLOR_RGB2LAB)
        if lab.dtype == np.uint8:      # a table: the same floats, ~6x faster than the arithmetic
            return cv2.LUT(lab, _LAB_TABLE)
        lab = lab.astype(np.float32)
        lab[..., 1:] = (lab[..., 1:] - 128) * 2
        return lab

    @cached_property
    def valid(self) -> np.ndarray:
        """The pixels with a depth reading (finite, > 0): asked for on every plane test."""
        return np.isfinite(self.depth) & (self.depth > 0)

    @cached_property
    def gap_kernel(self) -> np.ndarray:
        """Masks within `cat.max_join_gap_px` of each other are neighbours: the dilation kernel."""
        return np.ones((2 * self.cat.max_join_gap_px + 1,) * 2, np.uint8)

    def near(self, mask: np.ndarray) -> Near:
        """The pixels within the join gap of `mask` (`Near.touches`: whether a mask reaches them)."""
        return Near(mask, self.gap_kernel, self.cat.max_join_gap_px)


def neighbour_pieces(i: int, masks: list[np.ndarray], ctx: RepairContext,
                     plane: FrontFace | None = None) -> list[int]:
    """Indices of the masks next to mask i (within the join gap) that are pieces: measurable, no
    type face, not cut by the image border; with `plane` (a face), only those on its plane."""
    near = ctx.near(masks[i])
    out = []
    for j, o in enumerate(masks):
        if j == i or not near.touches(o) or border_sides(o):
            continue
        fo = ctx.measure(o)
        if fo is None or fo.err <= ctx.cat.tol:
            continue
        if plane is not None and plane_dist(plane, o, ctx) > ctx.cat.plane_tol:
            continue
        out.append(j)
    return out


def plane_dist(face: FrontFace, mask: np.ndarray, ctx: RepairContext) -> float:
    """Median distance (m) of the mask's depth points to the plane of `face` (memoised in
    `ctx.cache`: the steps ask it of the same pairs again after every change)."""
    if ctx.cache is None:
        return _plane_dist(face, mask, ctx)
    d = ctx.cache.dist(face, mask)
    if d is None:
        d = _plane_dist(face, mask, ctx)
        ctx.cache.put_dist(face, mask, d)
    return d


def _plane_dist(face: FrontFace, mask: np.ndarray, ctx: RepairContext) -> float:
    depth = ctx.depth
    ys, xs = box_nonzero(mask, ctx.valid)
    if len(xs) < 10:
        return math.inf
    if len(xs) > 3000:
        st = len(xs) // 3000 + 1
        ys, xs = ys[::st], xs[::st]
    p = backproject(ctx.camera, xs.astype(np.float64), ys.astype(np.float64), depth[ys, xs].astype(np.float64))
    n = face_axes(face)[:, 1]
    return float(np.median(np.abs((p - np.asarray(face.center)) @ n)))
