"""Box front faces without learned weights: depth discontinuities, surface normals, colour edges.

A box front face seen by the camera is a near-planar patch facing the camera,
bounded by depth jumps (boxes at different distances), normal creases (the top
face of a box below the camera) and colour edges (boxes side by side with
flush fronts). The segmenter
1. drops the shelf itself (points outside the shelf volume or on the back wall),
2. cuts the image at depth jumps and keeps camera-facing pixels: geometric patches,
3. cuts patches further at Canny edges of the RGB image; long straight edges are
   extended a few pixels so a seam that stops short at a T junction still cuts,
4. gives thin and small pieces (tape, edge bands, labels) to their nearest big piece,
5. joins a tape band or cross (thin, across the face, near its middle) with the
   same-colour pieces it separates when together they fill a rectangle,
6. merges neighbouring pieces whose colours match and whose union is still a
   rectangle, unless both are rectangles with an edge line along their whole
   common border (the seam between two boxes).
Steps 5 and 6, joining pieces into faces, live in `perception.piece_merge`.
Vectorised; a 640x480 frame takes about 0.1-0.3 s of the ~0.35 s of `perceive`.
"""
from __future__ import annotations

from dataclasses import replace

import cv2
import numpy as np

from shelfpick.perception.depth_edge_config import DepthEdgeConfig
from shelfpick.perception.masks import pixel_scale, scaled_px
from shelfpick.perception.piece_merge import merge_pieces, merge_tape
from shelfpick.perception.pixels import label_masks, label_sums
from shelfpick.perception.face_gate import inside_shelf_xyz
from shelfpick.perception.scene import Camera, Shelf, quat_to_matrix


def _small_holes(valid: np.ndarray, max_px: int) -> np.ndarray:
    """Invalid pixels in 8-connected groups of at most `max_px` pixels."""
    if max_px <= 0:
        return np.zeros_like(valid)
    n, lab, stats, _ = cv2.connectedComponentsWithStats((~valid).astype(np.uint8), connectivity=8)
    small = stats[:, cv2.CC_STAT_AREA] <= max_px
    small[0] = False
    return small.take(lab)              # small[lab]: a table read at every pixel, by take (~2x faster)


class DepthEdgeSegmenter:
    """`segment(rgb, depth) -> list[bool mask]`; bind a camera and shelf to drop the shelf."""

    name = "depth"

    def __init__(self, camera: Camera | None = None, shelf: Shelf | None = None,
                 config: DepthEdgeConfig | None = None):
        self.camera = camera
        self.shelf = shelf
        self.config = config or DepthEdgeConfig()

    def bind(self, camera: Camera | None, shelf: Shelf | None) -> "DepthEdgeSegmenter":
        return DepthEdgeSegmenter(camera, shelf, self.config)

    def rgb_only(self) -> "DepthEdgeSegmenter":
        """The settings for a photo without depth (a flat stand-in depth): no depth jump
        separates boxes there, so pieces are joined only when their union is a clean rectangle;
        and a thin strip at the image border is not taken for a face (no depth to tell)."""
        return DepthEdgeSegmenter(self.camera, self.shelf,
                                  replace(self.config, rect_fill=self.config.rgb_rect_fill, border_px=0,
                                          metric_px=False))

    # ------------------------------------------------------------------
    def segment(self, rgb: np.ndarray, depth: np.ndarray) -> list[np.ndarray]:
        labels = self.segment_labels(rgb, depth)
        n = int(labels.max())
        return label_masks(labels, n)

    def segment_labels(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """HxW uint16 labels 1..n of the faces (steps 1-6 of the module docstring)."""
        cfg = self.config
        h, w = depth.shape
        camera = self.camera or _guess_camera(w, h)
        ds = _smoothed_depth(depth, cfg.fill_hole_px)
        vs = ds > 0
        jump = _depth_jumps(ds, cfg) | ~vs
        pts = _camera_points(ds, vs, camera)
        fg = vs & self._facing(pts, camera) & ~jump
        if self.camera is not None and self.shelf is not None:
            fg &= _inside_shelf(pts, camera, self.shelf, cfg.wall_margin)
        # ---- geometric patches
        npatch, patch = cv2.connectedComponents(fg.astype(np.uint8), connectivity=4)
        if npatch <= 1:
            return np.zeros((h, w), np.uint16)
        # ---- colour edges cut patches further
        lab8 = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB)
        edges = _colour_edges(rgb, fg, depth, cfg, lab8)
        core = fg & ~edges
        npiece, piece = cv2.connectedComponents(core.astype(np.uint8), connectivity=4)
        # pixel scale (m per px) for metric sizes
        mpp = np.where(vs, ds / np.sqrt(camera.fx * camera.fy), 0.0).astype(np.float32)
        keep = _big_pieces(core, piece, npiece, mpp, cfg)
        kept = keep.take(piece)         # keep[piece], by take
        assigned = np.where(kept, piece, 0)
        # ---- pixels of a patch not in a big piece go to the nearest big piece of that patch
        assigned = _grow_within(assigned, patch, fg)
        # ---- merge pieces of one patch with matching colour and a rectangular union
        lab = lab8.astype(np.float32)
        # ---- tape: a band (or cross) of another colour between pieces of one colour
        kcore = core & kept
        merged = merge_tape(assigned, kcore, lab, mpp, cfg)
        merged = merge_pieces(merged, kcore, patch, lab, cfg, edges)
        merged = merge_tape(merged, kcore, lab, mpp, cfg)
        return _finish(merged, mpp, cfg)

    def _facing(self, pts: tuple[np.ndarray, np.ndarray, np.ndarray], camera: Camera) -> np.ndarray:
        """Pixels whose surface normal is within `facing_cos` of shelf +y (of the optical axis
        when no camera is bound)."""
        cfg = self.config
        k = cfg.normal_step
        du, dv = _tangents(pts, k, cfg.border_px > 0)
        nx = du[1] * dv[2] - du[2] * dv[1]
        ny = du[2] * dv[0] - du[0] * dv[2]
        nz = du[0] * dv[1] - du[1] * dv[0]
        nn = np.sqrt(nx * nx + ny * ny + nz * nz) + 1e-12
        if self.camera is not None:
            rot = np.asarray(_rot(camera))
            fwd = rot.T @ np.array([0.0, 1.0, 0.0])   # shelf +y in the camera frame
        else:
            fwd = np.array([0.0, 0.0, 1.0])
        facing = (nx * fwd[0] + ny * fwd[1] + nz * fwd[2]) / nn > cfg.facing_cos
        if self.camera is not None and cfg.border_px > 0:
            # the top 2k+1 rows: the vertical difference reaches past a strip cut by the image
            # border (the bottom of a box above the view) into whatever is below it; a front
            # face is vertical, so there its normal is the horizontal tangent x shelf up
            b = 2 * k + 1
            up = rot.T @ np.array([0.0, 0.0, 1.0])
            tx, ty, tz = du[0][:b], du[1][:b], du[2][:b]
            mx, my, mz = ty * up[2] - tz * up[1], tz * up[0] - tx * up[2], tx * up[1] - ty * up[0]
            mn = np.sqrt(mx * mx + my * my + mz * mz) + 1e-12
            facing[:b] = np.abs(mx * fwd[0] + my * fwd[1] + mz * fwd[2]) / mn > cfg.facing_cos
        return facing


def _smoothed_depth(depth: np.ndarray, fill_hole_px: int) -> np.ndarray:
    """The depth median-filtered (5x5), NaN read as no data (0); holes of more than
    `fill_hole_px` pixels stay 0."""
    d = np.nan_to_num(depth.astype(np.float32), nan=0.0)
    valid = d > 0
    ds = cv2.medianBlur(d, 5)
    # a hole of a few pixels inside a surface (sensor speckle, an inf or NaN read as no data)
    # takes the median around it: left as a hole, every one cuts the surface like a depth
    # jump, and 10% scattered holes left no face at all
    ds[~valid & ~_small_holes(valid, fill_hole_px)] = 0.0
    return ds


def _depth_jumps(ds: np.ndarray, cfg: DepthEdgeConfig) -> np.ndarray:
    """Pixels on either side of a depth step larger than the noise-scaled threshold."""
    h, w = ds.shape
    thr = cfg.jump_abs + cfg.jump_rel * ds * ds
    jump = np.zeros((h, w), bool)
    dx = np.abs(np.diff(ds, axis=1)) > np.minimum(thr[:, 1:], thr[:, :-1])
    dy = np.abs(np.diff(ds, axis=0)) > np.minimum(thr[1:, :], thr[:-1, :])
    jump[:, 1:] |= dx
    jump[:, :-1] |= dx
    jump[1:, :] |= dy
    jump[:-1, :] |= dy
    return jump


def _camera_points(ds: np.ndarray, vs: np.ndarray,
                   camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Camera-frame x, y, z per pixel from the depth box-smoothed over its valid pixels."""
    h, w = ds.shape
    fx, fy = camera.fx, camera.fy
    uu = ((np.arange(w, dtype=np.float32) - camera.cx) / fx)[None, :]
    vv = ((np.arange(h, dtype=np.float32) - camera.cy) / fy)[:, None]
    wgt = cv2.blur(vs.astype(np.float32), (5, 5))
    dsm = cv2.blur(ds, (5, 5)) / np.maximum(wgt, 1e-6)
    return uu * dsm, vv * dsm, dsm


def _tangents(pts: tuple[np.ndarray, np.ndarray, np.ndarray], k: int,
              to_border: bool) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Central differences (half step `k`) of the points along image x (du) and y (dv)."""
    du = [np.zeros_like(pts[2]) for _ in range(3)]
    dv = [np.zeros_like(pts[2]) for _ in range(3)]
    for i, p in enumerate(pts):
        du[i][:, k:-k] = p[:, 2 * k:] - p[:, :-2 * k]
        dv[i][k:-k, :] = p[2 * k:, :] - p[:-2 * k, :]
        if to_border:
            # the first k rows and the first/last k columns take the nearest full
            # difference: a face cut by the top or a side border keeps its normal up to the
            # border (the bottom border stays as it was: the floor in front of the shelf)
            du[i][:, :k], du[i][:, -k:] = du[i][:, k:k + 1], du[i][:, -k - 1:-k]
            dv[i][:k, :] = dv[i][k:k + 1, :]
    return du, dv


def _inside_shelf(pts: tuple[np.ndarray, np.ndarray, np.ndarray], camera: Camera, s: Shelf,
                  m: float) -> np.ndarray:
    """Pixels inside the shelf volume and more than `m` in front of its back wall (the shelf
    itself is no box)."""
    px, py, pz = pts
    rot = np.asarray(_rot(camera), dtype=np.float32)
    t = np.asarray(camera.position, dtype=np.float32)
    sx = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz + t[0]
    sy = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz + t[1]
    sz = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz + t[2]
    return inside_shelf_xyz(sx, sy, sz, s, m)


def _colour_edges(rgb: np.ndarray, fg: np.ndarray, depth: np.ndarray, cfg: DepthEdgeConfig,
                  lab8: np.ndarray) -> np.ndarray:
    """Canny edges of grey and (scaled) Lab chroma, long straight ones extended over `fg`,
    dilated 3x3. `lab8`: the image in 8-bit Lab, which the caller has already (its chroma is
    scaled through a lookup table of the 256 values)."""
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    gray = cv2.GaussianBlur(gray, (3, 3), 0)
    edges = cv2.Canny(gray, cfg.canny_low, cfg.canny_high) > 0
    # hue seams that grey levels miss (two browns of one brightness)
    lab8 = cv2.GaussianBlur(lab8, (3, 3), 0)
    gain = _chroma_lut(cfg.chroma_gain)
    for c in (1, 2) if cfg.chroma_gain > 0 else ():
        edges |= cv2.Canny(gain.take(lab8[..., c]), cfg.canny_low, cfg.canny_high) > 0
    edges = _extend_lines(edges, fg, _scaled(cfg, depth, fg))
    return cv2.dilate(edges.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0


def _chroma_lut(gain: float) -> np.ndarray:
    """uint8 -> uint8: a Lab chroma channel's value scaled by `gain` about 128 and clipped (the
    per-pixel float arithmetic done once for each of the 256 values)."""
    return np.clip((np.arange(256, dtype=np.uint8).astype(np.float32) - 128) * gain + 128, 0, 255
                   ).astype(np.uint8)


def _big_pieces(core: np.ndarray, piece: np.ndarray, npiece: int, mpp: np.ndarray,
                cfg: DepthEdgeConfig) -> np.ndarray:
    """keep[label]: the pieces big and thick enough to be (part of) a face; the rest (tape,
    edge bands, labels) go to their neighbours."""
    h, w = core.shape
    dist = cv2.distanceTransform(core.astype(np.uint8), cv2.DIST_L2, 3)
    idx = np.arange(1, npiece)
    area_m2 = label_sums(mpp * mpp, piece, idx) if npiece > 1 else np.zeros(0)
    thick_m = 2 * label_max(dist * mpp, piece, npiece) if npiece > 1 else np.zeros(0)
    big = (area_m2 >= 0.4 * cfg.min_face_m2) & (thick_m >= cfg.min_side_m)
    if npiece > 1 and cfg.border_px > 0:
        # a face cut by the image border is at least this big: a thin strip along the
        # border (the bottom of a box above the view) is a face, not tape
        edge = np.zeros((h, w), bool)
        b = cfg.border_px
        edge[:b, :] = True
        edge[:, :b] = edge[:, -b:] = True
        on_edge = label_sums(edge, piece, idx) >= cfg.border_min_px if npiece > 1 else np.zeros(0, bool)
        big |= on_edge & (area_m2 >= 0.4 * cfg.min_face_m2) & (thick_m >= cfg.border_side_m)
    keep = np.zeros(npiece, bool)
    keep[1:] = big
    return keep


def label_max(values: np.ndarray, labels: np.ndarray, n: int) -> np.ndarray:
    """The largest value of each label 1..n-1 (labels 0..n-1, each present): what
    `ndimage.maximum(values, labels, range(1, n))` gives, without its sort of the whole image
    (57 ms of a frame's CPU)."""
    out = np.full(n, -np.inf, values.dtype)
    lab, vals = labels.ravel(), values.ravel()
    on = lab != 0                       # label 0 (most of the frame) is not asked for
    np.maximum.at(out, lab[on], vals[on])
    return out[1:]


def _scaled(cfg: DepthEdgeConfig, depth: np.ndarray, fg: np.ndarray) -> DepthEdgeConfig:
    """The straight-line threshold (px) at the capture's pixel scale (f / depth of the
    camera-facing pixels relative to the tuning distance); unchanged without real depth."""
    s = pixel_scale(depth, fg) if cfg.metric_px else 1.0
    if s == 1.0:
        return cfg
    # only the shortest line: a seam spans fewer pixels further back. The extension (a gap left
    # by smoothing at a T junction) and the Hough votes (edge noise) are pixel effects; scaling
    # the votes down too cut a 50x17 face at its tape edges (seed 201 at 1.6 m).
    return replace(cfg, line_min=scaled_px(cfg.line_min, s, 8))


def _extend_lines(edges: np.ndarray, fg: np.ndarray, cfg: DepthEdgeConfig) -> np.ndarray:
    """Close the gaps where a seam's Canny line stops short of the face border.

    A seam between two flush boxes is a long straight line; Canny often leaves a
    few pixels open where it meets the depth boundary (a T junction), and one open
    pixel joins two boxes into one piece. Long straight segments are drawn again,
    extended by `line_extend` px at both ends, but only over foreground.
    """
    if cfg.line_extend <= 0:
        return edges
    lines = cv2.HoughLinesP(edges.astype(np.uint8) * 255, 1, np.pi / 180, cfg.line_votes,
                            minLineLength=cfg.line_min, maxLineGap=3)
    if lines is None:
        return edges
    extra = np.zeros(edges.shape, np.uint8)
    for x1, y1, x2, y2 in lines.reshape(-1, 4).astype(float):
        d = np.hypot(x2 - x1, y2 - y1)
        if d < 1:
            continue
        ux, uy = (x2 - x1) / d, (y2 - y1) / d
        e = cfg.line_extend
        p1 = (int(round(x1 - ux * e)), int(round(y1 - uy * e)))
        p2 = (int(round(x2 + ux * e)), int(round(y2 + uy * e)))
        cv2.line(extra, p1, p2, 1, 1)
    return edges | ((extra > 0) & fg)


def _rot(camera: Camera):
    return quat_to_matrix(camera.orientation)


def _guess_camera(w: int, h: int) -> Camera:
    f = 0.95 * w
    return Camera(w, h, f, f, w / 2, h / 2)


def _grow_within(assigned: np.ndarray, patch: np.ndarray, fg: np.ndarray) -> np.ndarray:
    """Give every foreground pixel without a piece the label of its nearest piece in the same patch."""
    if assigned.max() == 0:
        return assigned
    todo = fg & (assigned == 0)
    if not todo.any():
        return assigned
    src = (assigned == 0).astype(np.uint8)
    _, lbl = cv2.distanceTransformWithLabels(src, cv2.DIST_L2, 3, labelType=cv2.DIST_LABEL_PIXEL)
    # map the zero-pixel index back to its label: build a lookup from seed index -> piece label
    seeds = assigned != 0
    lut = np.zeros(int(lbl.max()) + 1, np.int32)
    lut[lbl[seeds]] = assigned[seeds]
    nearest = lut.take(lbl)
    patch_of = np.zeros(int(assigned.max()) + 1, np.int32)
    patch_of[assigned[seeds]] = patch[seeds]
    ok = todo & (patch_of.take(nearest) == patch) & (nearest > 0)
    out = assigned.copy()
    out[ok] = nearest[ok]
    return out


def _finish(merged: np.ndarray, mpp: np.ndarray, cfg: DepthEdgeConfig) -> np.ndarray:
    """Relabel 1..n, dropping faces too small to be a box."""
    labels = np.flatnonzero(np.bincount(merged.ravel()))     # np.unique's labels, without its sort
    labels = labels[labels > 0]
    if len(labels) == 0:
        return np.zeros(merged.shape, np.uint16)
    area = label_sums(mpp * mpp, merged, labels)
    lut = np.zeros(int(labels[-1]) + 1, np.uint16)
    kept = labels[~(area < cfg.min_face_m2)]
    lut[kept] = np.arange(1, len(kept) + 1)
    return lut.take(merged)
