"""Matter the depth image shows inside the shelf that no perceived box explains.

The depth image says where matter is, whatever the segmenter says. Every valid depth
point inside the shelf volume is explained by the shelf (within `EXPLAIN_TOL` of the
floor, a side wall, the back wall or the top), or by a perceived box (within
`EXPLAIN_TOL` of the prism its front face sweeps from just in front of the face back to
the back wall: everything a box of unknown depth may be), or it is unexplained. The
unexplained points are cleaned of flying pixels and depth-edge speckle (an opening,
then split at depth steps), grouped into connected regions, and a region smaller than
`MIN_AREA_M2` (or `MIN_PIXELS`) is noise, not matter. What is left is reported: a
region is never dropped for not being a box. A mask perception refused as "not a box
front" is not nothing either: its points are unexplained like any other, and the region
says which mask it was (`why`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from shelfpick.perception.geometry import offsets, point_map
from shelfpick.perception.scene import (EXPLAIN_TOL, FRONT_REACH, Box, Camera, Shelf, Unexplained,  # noqa: F401
                              quat_to_matrix)

# a box's top seen from above may stand this much (m) above its face's measured top plus
# EXPLAIN_TOL: a face measured a few cm short leaves its own top surface behind the face
TOP_SLACK = 0.04
# the smallest region reported: 0.002 m^2 (about 4.5 x 4.5 cm of seen surface) ...
MIN_AREA_M2 = 0.002
# ... and at least this many pixels at 640x480 (scaled with the image's pixel count)
MIN_PIXELS = 60
# radius (m, at the unexplained points' median depth) of the opening that removes what is thinner
# than about twice this across: flying-pixel lines, speckle, and the bands a face measured a few cm
# short leaves along its edge beyond EXPLAIN_TOL (a box top seen at a grazing angle, a top row)
OPEN_M = 0.015
# neighbouring points further apart than this along the camera axis (m) are not one region
DEPTH_STEP = 0.03
# side (m) of the grid a region's seen surface is cut into for `Unexplained.columns`
COLUMN = 0.04


@dataclass(frozen=True, eq=False)
class Found:
    """The regions found and their pixels (label k+1 = regions[k]; 0 elsewhere)."""

    regions: tuple[Unexplained, ...]
    labels: np.ndarray


def shelf_parts(p: np.ndarray, shelf: Shelf, tol: float = EXPLAIN_TOL) -> np.ndarray:
    """Points the shelf itself explains: near the floor, a side wall, the back wall or the top."""
    return ((p[..., 2] < tol) | (np.abs(p[..., 0]) > shelf.width / 2 - tol)
            | (p[..., 1] > shelf.depth - tol) | (p[..., 2] > shelf.height - tol))


def inside(p: np.ndarray, valid: np.ndarray, shelf: Shelf) -> np.ndarray:
    """Valid points inside the shelf volume (its front plane moved `FRONT_REACH` forward)."""
    with np.errstate(invalid="ignore"):
        return (valid & (np.abs(p[..., 0]) <= shelf.width / 2) & (p[..., 1] >= -FRONT_REACH)
                & (p[..., 1] <= shelf.depth) & (p[..., 2] >= 0.0) & (p[..., 2] <= shelf.height))


def explained_by(points: np.ndarray, box: Box, tol: float = EXPLAIN_TOL) -> np.ndarray:
    """Which of the points (N,3) lie in `box`'s face prism: within `tol` of its front face
    rectangle across, from `tol` in front of the face to anywhere behind it (its depth is
    unknown; the shelf volume bounds it); behind the face (not on it) up to `TOP_SLACK` higher
    still (the box's own top, seen from above, of a face measured short)."""
    r = np.asarray(quat_to_matrix(box.orientation), np.float32)
    q = offsets(points, np.asarray(box.front_center, np.float32))
    loc = q @ r                     # the box's own x, y (depth), z of every point
    h = box.size[2] / 2 + tol
    top = (loc[:, 1] >= tol) & (loc[:, 2] > h) & (loc[:, 2] <= h + TOP_SLACK)
    return ((np.abs(loc[:, 0]) <= box.size[0] / 2 + tol) & (loc[:, 1] >= -tol)
            & ((np.abs(loc[:, 2]) <= h) | top))


def candidates(depth: np.ndarray, camera: Camera, shelf: Shelf) -> tuple[np.ndarray, np.ndarray]:
    """(HxWx3 shelf-frame points, flat indices of the valid ones inside the shelf volume that
    the shelf itself does not explain): what every box is then asked about."""
    d = np.asarray(depth, np.float32)
    valid = np.isfinite(d) & (d > 0)
    p = point_map(camera, np.where(valid, d, 0.0).astype(np.float32))
    return p, np.flatnonzero(inside(p, valid, shelf) & ~shelf_parts(p, shelf))


def unexplained_points(depth: np.ndarray, camera: Camera, shelf: Shelf, boxes: Sequence[Box],
                       labels: np.ndarray | None = None,
                       cand: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(HxW mask of unexplained points, HxWx3 shelf-frame points). `labels`: the boxes' masks
    (label = `Box.mask_label`): a box's own pixels are tested against it first, the rest
    against every box (the same answer, fewer points to test). `cand`: `candidates` of this
    depth, when known already."""
    d = np.asarray(depth, np.float32)
    p, flat = cand if cand is not None else candidates(depth, camera, shelf)
    pts = p.reshape(-1, 3).take(flat, axis=0)      # rows by take: 3x faster than p[flat] here
    keep = np.ones(len(flat), bool)
    if labels is not None and len(flat):
        lab = labels.ravel()[flat]
        order = np.argsort(lab)
        sorted_lab = lab[order]
        for b in boxes:
            if b.mask_label is None:
                continue
            lo, hi = np.searchsorted(sorted_lab, [b.mask_label, b.mask_label + 1])
            idx = order[lo:hi]
            keep[idx[explained_by(pts.take(idx, axis=0), b)]] = False
    for b in boxes:
        if not keep.any():
            break
        idx = np.flatnonzero(keep)
        keep[idx[explained_by(pts.take(idx, axis=0), b)]] = False
    out = np.zeros(d.size, bool)
    out[flat[keep]] = True
    return out.reshape(d.shape), p


def _clean(mask: np.ndarray, depth: np.ndarray, camera: Camera) -> np.ndarray:
    """The mask opened (whatever is thinner than ~2 x `OPEN_M` across goes) and cut where
    neighbours differ in depth by more than `DEPTH_STEP` (two things at two depths are two regions)."""
    z = float(np.median(depth[mask]))
    r = max(1, int(round(OPEN_M * np.sqrt(camera.fx * camera.fy) / max(z, 0.1))))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * r + 1, 2 * r + 1))
    m = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_OPEN, k) > 0
    d = np.where(m, depth, np.nan).astype(np.float32)
    step = np.zeros(m.shape, bool)
    with np.errstate(invalid="ignore"):
        dy = np.abs(np.diff(d, axis=0)) > DEPTH_STEP
        dx = np.abs(np.diff(d, axis=1)) > DEPTH_STEP
    step[1:] |= dy
    step[:-1] |= dy
    step[:, 1:] |= dx
    step[:, :-1] |= dx
    return m & ~step


def _columns(pts: np.ndarray, cell: float = COLUMN) -> tuple[tuple[float, float, float, float, float], ...]:
    """The seen surface as x-z rectangles on a `cell` grid (each the bounds of its points and
    their nearest y, 5th percentile), cells in one grid column with near y merged."""
    cell = max(cell, float(np.sqrt((np.ptp(pts[:, 0]) + cell) * (np.ptp(pts[:, 2]) + cell) / 300.0)))
    ix = np.floor((pts[:, 0] - pts[:, 0].min()) / cell).astype(np.int64)
    iz = np.floor((pts[:, 2] - pts[:, 2].min()) / cell).astype(np.int64)
    key = ix * 100000 + iz
    order = np.argsort(key, kind="stable")
    key, p = key[order], pts[order]
    cuts = np.flatnonzero(np.diff(key)) + 1
    cells: dict[int, list[tuple[int, list[float]]]] = {}
    for grp, k in zip(np.split(p, cuts), key[np.r_[0, cuts]]):
        if len(grp) < 3:
            continue
        c = [float(grp[:, 0].min()), float(grp[:, 0].max()), float(grp[:, 2].min()), float(grp[:, 2].max()),
             float(np.percentile(grp[:, 1], 5))]
        cells.setdefault(int(k // 100000), []).append((int(k % 100000), c))
    out = []
    for _, run in sorted(cells.items()):
        cur: list[float] | None = None
        last = -2
        for z_i, c in run:
            if cur is not None and z_i == last + 1 and abs(c[4] - cur[4]) <= EXPLAIN_TOL:
                cur = [min(cur[0], c[0]), max(cur[1], c[1]), min(cur[2], c[2]), max(cur[3], c[3]), min(cur[4], c[4])]
            else:
                if cur is not None:
                    out.append(tuple(cur))
                cur = list(c)
            last = z_i
        if cur is not None:
            out.append(tuple(cur))
    return tuple(out)  # type: ignore[return-value]


def _why(sel: np.ndarray, dropped: Sequence[tuple[int, np.ndarray]]) -> str:
    """Which refused masks this region is mostly made of ('' for none)."""
    n = int(sel.sum())
    names = [f"mask {i}" for i, m in dropped if int((sel & m).sum()) >= 0.3 * min(n, int(m.sum()) or 1)]
    if not names:
        return ""
    return f"{', '.join(names)} refused as no box front"


def find_unexplained(depth: np.ndarray, camera: Camera, shelf: Shelf, boxes: Sequence[Box],
                     labels: np.ndarray | None = None,
                     dropped: Sequence[tuple[int, np.ndarray]] = (),
                     cand: tuple[np.ndarray, np.ndarray] | None = None) -> Found:
    """The unexplained regions of a capture (see the module docstring), biggest first, ids u0..
    `labels`: the boxes' mask labels and `cand` (`candidates` of this depth): speed-ups only;
    `dropped`: (mask number, mask) of the masks perception refused, named in the regions."""
    raw, p = unexplained_points(depth, camera, shelf, boxes, labels, cand)
    h, w = raw.shape
    out = np.zeros((h, w), np.uint16)
    if not raw.any():
        return Found((), out)
    d = np.asarray(depth, np.float32)
    m = _clean(raw, d, camera)
    n, lbl, stats, _ = cv2.connectedComponentsWithStats(m.astype(np.uint8), connectivity=8)
    min_px = max(8, int(round(MIN_PIXELS * h * w / (640 * 480))))
    found = []
    for k in range(1, n):
        if stats[k, cv2.CC_STAT_AREA] < min_px:
            continue
        sel = lbl == k
        z = d[sel].astype(np.float64)
        area = float(np.sum(z * z) / (camera.fx * camera.fy))   # each pixel's footprint facing the camera
        if area < MIN_AREA_M2:
            continue
        found.append((area, k, sel))
    found.sort(key=lambda t: -t[0])
    regions = []
    for i, (area, _, sel) in enumerate(found):
        pts = p[sel].astype(np.float64)
        lo = np.percentile(pts, 0.5, axis=0)
        hi = np.percentile(pts, 99.5, axis=0)
        regions.append(Unexplained(f"u{i}", _mm(lo), _mm(hi), int(sel.sum()), round(area, 5),  # type: ignore[arg-type]
                                   tuple(_mm(c) for c in _columns(pts)), _why(sel, dropped)))
        out[sel] = i + 1
    return Found(tuple(regions), out)


def _mm(values) -> tuple[float, ...]:
    """Metres to 0.1 mm (what a depth camera resolves at best): short scene files."""
    return tuple(round(float(v), 4) for v in values)


def describe(regions: Sequence[Unexplained]) -> str:
    """One warning line: how many regions, where and how large ('' for none)."""
    if not regions:
        return ""
    parts = []
    for u in regions:
        cx, cz = (u.min[0] + u.max[0]) / 2, (u.min[2] + u.max[2]) / 2
        what = (f"{u.id} at x={cx:.2f} z={cz:.2f} m, front at y={u.min[1]:.2f} m, "
                f"{(u.max[0] - u.min[0]) * 100:.0f}x{(u.max[2] - u.min[2]) * 100:.0f} cm, "
                f"{u.area_m2:.3f} m^2 ({u.pixels} px)")
        parts.append(f"{what}: {u.why}" if u.why else what)
    n = len(regions)
    return (f"{n} region{'s' if n != 1 else ''} of matter inside the shelf that no perceived box explains "
            f"(planning treats {'them' if n != 1 else 'it'} as obstacles reaching to the back wall): "
            + "; ".join(parts))
