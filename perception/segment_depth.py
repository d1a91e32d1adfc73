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
Vectorised; a 640x480 frame takes about 0.1-0.3 s of the ~0.35 s of `perceive`.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from perception.scene import Camera, Shelf


@dataclass(frozen=True)
class DepthEdgeConfig:
    jump_abs: float = 0.012          # m: depth step between neighbours that separates surfaces
    jump_rel: float = 0.012          # m per m^2 of depth: grows with the sensor's noise
    facing_cos: float = 0.80         # cos of the largest angle between face normal and shelf +y
    normal_step: int = 3             # px: finite-difference half step for normals
    canny_low: int = 40
    canny_high: int = 110
    line_extend: int = 14             # px: long straight edges are extended this far (seam gaps)
    line_min: int = 30               # px: shortest straight edge that is extended
    line_votes: int = 25
    chroma_gain: float = 2   # Lab a/b channels scaled by this before their own Canny
    min_face_m2: float = 0.0025      # smallest front face kept (5 x 5 cm)
    min_side_m: float = 0.04         # thinner pieces are tape/edges, not faces
    colour_merge: float = 11.0       # Lab distance under which two pieces are one box
    seam_veto: float = 0.5           # pieces whose border is more than this much colour edge stay apart
    seam_rect: float = 0.8           # ... when both are rectangles at least this full
    rgb_rect_fill: float = 0.86      # the same for photos without depth (`rgb_only`)
    rect_fill: float = 0.65          # a merged piece must fill its min-area rectangle this well
    tape_max_m: float = 0.09         # a tape band is at most this thick ...
    tape_rel: float = 1.25           # ... and at most this fraction of the pieces it joins
    tape_frac: float = 0.35          # ... at most this fraction of the face across the tape
    tape_centre: float = 0.3         # ... and its centre this close to the face's (of its size)
    tape_span: float = 0.85          # ... and runs across at least this fraction of the face
    tape_colour: float = 20.0        # Lab distance between the pieces on both sides of a tape
    wall_margin: float = 0.012       # m: points this close to the back wall are the shelf
    border_px: int = 3               # px: a piece this close to the image border may be cut by it ...
    border_min_px: int = 20          # ... when this many of its pixels are there; it is then kept ...
    border_side_m: float = 0.004     # ... down to this thickness (a strip of a face above the view)
    metric_px: bool = True           # line_min scales with f / depth (masks.pixel_scale)
    fill_hole_px: int = 4            # depth holes of at most this many pixels are filled for segmenting


def _small_holes(valid: np.ndarray, max_px: int) -> np.ndarray:
    """Invalid pixels in 8-connected groups of at most `max_px` pixels."""
    import cv2

    if max_px <= 0:
        return np.zeros_like(valid)
    n, lab, stats, _ = cv2.connectedComponentsWithStats((~valid).astype(np.uint8), connectivity=8)
    small = stats[:, cv2.CC_STAT_AREA] <= max_px
    small[0] = False
    return small[lab]


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
        return [labels == k for k in range(1, n + 1)]

    def segment_labels(self, rgb: np.ndarray, depth: np.ndarray) -> np.ndarray:
        import cv2

        cfg = self.config
        h, w = depth.shape
        camera = self.camera or _guess_camera(w, h)
        d = np.nan_to_num(depth.astype(np.float32), nan=0.0)
        valid = d > 0
        ds = cv2.medianBlur(d, 5)
        # a hole of a few pixels inside a surface (sensor speckle, an inf or NaN read as no data)
        # takes the median around it: left as a hole, every one cuts the surface like a depth
        # jump, and 10% scattered holes left no face at all
        ds[~valid & ~_small_holes(valid, cfg.fill_hole_px)] = 0.0
        # ---- depth jumps (both sides of the step are boundary)
        thr = cfg.jump_abs + cfg.jump_rel * ds * ds
        jump = np.zeros((h, w), bool)
        dx = np.abs(np.diff(ds, axis=1)) > np.minimum(thr[:, 1:], thr[:, :-1])
        dy = np.abs(np.diff(ds, axis=0)) > np.minimum(thr[1:, :], thr[:-1, :])
        jump[:, 1:] |= dx
        jump[:, :-1] |= dx
        jump[1:, :] |= dy
        jump[:-1, :] |= dy
        vs = ds > 0
        jump |= ~vs
        # ---- camera-frame points and normals from smoothed depth
        fx, fy = camera.fx, camera.fy
        uu = ((np.arange(w, dtype=np.float32) - camera.cx) / fx)[None, :]
        vv = ((np.arange(h, dtype=np.float32) - camera.cy) / fy)[:, None]
        wgt = cv2.blur(vs.astype(np.float32), (5, 5))
        dsm = cv2.blur(ds, (5, 5)) / np.maximum(wgt, 1e-6)
        px, py, pz = uu * dsm, vv * dsm, dsm
        k = cfg.normal_step
        du = [np.zeros_like(dsm) for _ in range(3)]
        dv = [np.zeros_like(dsm) for _ in range(3)]
        for i, p in enumerate((px, py, pz)):
            du[i][:, k:-k] = p[:, 2 * k:] - p[:, :-2 * k]
            dv[i][k:-k, :] = p[2 * k:, :] - p[:-2 * k, :]
            if cfg.border_px > 0:
                # the first k rows and the first/last k columns take the nearest full
                # difference: a face cut by the top or a side border keeps its normal up to the
                # border (the bottom border stays as it was: the floor in front of the shelf)
                du[i][:, :k], du[i][:, -k:] = du[i][:, k:k + 1], du[i][:, -k - 1:-k]
                dv[i][:k, :] = dv[i][k:k + 1, :]
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
        fg = vs & facing & ~jump
        # ---- the shelf itself
        if self.camera is not None and self.shelf is not None:
            rot = np.asarray(_rot(camera), dtype=np.float32)
            t = np.asarray(camera.position, dtype=np.float32)
            sx = rot[0, 0] * px + rot[0, 1] * py + rot[0, 2] * pz + t[0]
            sy = rot[1, 0] * px + rot[1, 1] * py + rot[1, 2] * pz + t[1]
            sz = rot[2, 0] * px + rot[2, 1] * py + rot[2, 2] * pz + t[2]
            s = self.shelf
            m = cfg.wall_margin
            inside = (sy < s.depth - m) & (np.abs(sx) < s.width / 2 - 0.003) & (sz > 0.005) \
                & (sz < s.height - 0.003)
            fg &= inside
        # ---- geometric patches
        npatch, patch = cv2.connectedComponents(fg.astype(np.uint8), connectivity=4)
        if npatch <= 1:
            return np.zeros((h, w), np.uint16)
        # ---- colour edges cut patches further
        gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
        gray = cv2.GaussianBlur(gray, (3, 3), 0)
        edges = cv2.Canny(gray, cfg.canny_low, cfg.canny_high) > 0
        # hue seams that grey levels miss (two browns of one brightness)
        lab8 = cv2.GaussianBlur(cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB), (3, 3), 0)
        for c in (1, 2) if cfg.chroma_gain > 0 else ():
            ch = np.clip((lab8[..., c].astype(np.float32) - 128) * cfg.chroma_gain + 128, 0, 255
                         ).astype(np.uint8)
            edges |= cv2.Canny(ch, cfg.canny_low, cfg.canny_high) > 0
        edges = _extend_lines(edges, fg, _scaled(cfg, depth, fg))
        edges = cv2.dilate(edges.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        core = fg & ~edges
        npiece, piece = cv2.connectedComponents(core.astype(np.uint8), connectivity=4)
        # pixel scale (m per px) for metric sizes
        mpp = np.where(vs, ds / np.sqrt(fx * fy), 0.0).astype(np.float32)
        dist = cv2.distanceTransform(core.astype(np.uint8), cv2.DIST_L2, 3)
        idx = np.arange(1, npiece)
        from scipy import ndimage

        area_m2 = ndimage.sum(mpp * mpp, piece, idx) if npiece > 1 else np.zeros(0)
        thick_m = 2 * ndimage.maximum(dist * mpp, piece, idx) if npiece > 1 else np.zeros(0)
        big = (area_m2 >= 0.4 * cfg.min_face_m2) & (thick_m >= cfg.min_side_m)
        if npiece > 1 and cfg.border_px > 0:
            # a face cut by the image border is at least this big: a thin strip along the
            # border (the bottom of a box above the view) is a face, not tape
            edge = np.zeros((h, w), bool)
            b = cfg.border_px
            edge[:b, :] = True
            edge[:, :b] = edge[:, -b:] = True
            on_edge = ndimage.sum(edge, piece, idx) >= cfg.border_min_px if npiece > 1 else np.zeros(0, bool)
            big |= on_edge & (area_m2 >= 0.4 * cfg.min_face_m2) & (thick_m >= cfg.border_side_m)
        keep = np.zeros(npiece, bool)
        keep[1:] = big
        assigned = np.where(keep[piece], piece, 0)
        # ---- pixels of a patch not in a big piece go to the nearest big piece of that patch
        assigned = _grow_within(assigned, patch, fg)
        # ---- merge pieces of one patch with matching colour and a rectangular union
        lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
        # ---- tape: a band (or cross) of another colour between pieces of one colour
        kcore = core & keep[piece]
        merged = _merge_tape(assigned, kcore, lab, mpp, cfg)
        merged = _merge_pieces(merged, kcore, patch, lab, cfg, edges)
        merged = _merge_tape(merged, kcore, lab, mpp, cfg)
        return _finish(merged, mpp, cfg)


def _scaled(cfg: DepthEdgeConfig, depth: np.ndarray, fg: np.ndarray) -> DepthEdgeConfig:
    """The straight-line threshold (px) at the capture's pixel scale (f / depth of the
    camera-facing pixels relative to the tuning distance); unchanged without real depth."""
    from perception.masks import pixel_scale, scaled_px

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
    import cv2

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
    from perception.scene import quat_to_matrix

    return quat_to_matrix(camera.orientation)


def _guess_camera(w: int, h: int) -> Camera:
    f = 0.95 * w
    return Camera(w, h, f, f, w / 2, h / 2)


def _grow_within(assigned: np.ndarray, patch: np.ndarray, fg: np.ndarray) -> np.ndarray:
    """Give every foreground pixel without a piece the label of its nearest piece in the same patch."""
    import cv2

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
    nearest = lut[lbl]
    patch_of = np.zeros(int(assigned.max()) + 1, np.int32)
    patch_of[assigned[seeds]] = patch[seeds]
    ok = todo & (patch_of[nearest] == patch) & (nearest > 0)
    out = assigned.copy()
    out[ok] = nearest[ok]
    return out


def _merge_pieces(assigned: np.ndarray, core: np.ndarray, patch: np.ndarray, lab: np.ndarray,
                  cfg: DepthEdgeConfig, edges: np.ndarray | None = None) -> np.ndarray:
    import cv2
    from scipy import ndimage

    n = int(assigned.max())
    if n <= 1:
        return assigned
    idx = np.arange(1, n + 1)
    src = np.where(core, assigned, 0)
    cnt = np.maximum(ndimage.sum(np.ones_like(src), src, idx), 1)
    mean = np.stack([ndimage.sum(lab[..., c], src, idx) / cnt for c in range(3)], axis=1)
    # neighbouring pieces (one pixel apart after growing)
    pairs = set()
    for a, b in ((assigned[:, :-1], assigned[:, 1:]), (assigned[:-1, :], assigned[1:, :])):
        sel = (a != b) & (a > 0) & (b > 0)
        if sel.any():
            code = np.unique(np.minimum(a[sel], b[sel]).astype(np.int64) * (n + 1)
                             + np.maximum(a[sel], b[sel]))
            pairs.update((int(c // (n + 1)), int(c % (n + 1))) for c in code)
    parent = list(range(n + 1))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    cand = []
    for a, b in pairs:
        de = float(np.linalg.norm(mean[a - 1] - mean[b - 1]))
        if de < cfg.colour_merge:
            cand.append((de, a, b))
    cand.sort()
    members: dict[int, list[int]] = {i: [i] for i in range(1, n + 1)}
    seam = _seam_fraction(assigned, edges) if edges is not None and cfg.seam_veto < 1 else {}
    for _, a, b in cand:
        ra, rb = find(a), find(b)
        if ra == rb:
            continue
        if seam.get((a, b), 0.0) > cfg.seam_veto and \
                min(_rect_fill(np.isin(assigned, members[r])) for r in (ra, rb)) >= cfg.seam_rect:
            continue        # two rectangles with an edge line all along their border: two boxes
        union = np.isin(assigned, members[ra] + members[rb])
        if _rect_fill(union) < cfg.rect_fill:
            continue
        parent[rb] = ra
        members[ra] = members[ra] + members.pop(rb)
    lut = np.zeros(n + 1, np.int32)
    for i in range(1, n + 1):
        lut[i] = find(i)
    return lut[assigned]


def _contacts(labels: np.ndarray) -> dict[tuple[int, int], int]:
    """(a, b) with a < b -> number of 4-neighbour pixel pairs where label a touches label b."""
    n = int(labels.max())
    out: dict[tuple[int, int], int] = {}
    for a, b in ((labels[:, :-1], labels[:, 1:]), (labels[:-1, :], labels[1:, :])):
        sel = (a != b) & (a > 0) & (b > 0)
        if not sel.any():
            continue
        code = np.minimum(a[sel], b[sel]).astype(np.int64) * (n + 1) + np.maximum(a[sel], b[sel])
        u, c = np.unique(code, return_counts=True)
        for k, v in zip(u, c):
            key = (int(k // (n + 1)), int(k % (n + 1)))
            out[key] = out.get(key, 0) + int(v)
    return out


def _merge_tape(labels: np.ndarray, core: np.ndarray, lab: np.ndarray, mpp: np.ndarray,
                cfg: DepthEdgeConfig) -> np.ndarray:
    """Join a tape piece with the pieces it separates.

    Tape across a face (a band, or a cross of two) is a piece of another colour
    that cuts the face into parts of one colour. A piece P is taken for tape when
    it is thin (<= `tape_max_m`, and clearly thinner than its neighbours), at least
    two of its neighbours share a colour, and P with those neighbours fills a
    rectangle. Two stacked boxes flush with a thin third one between them would
    fool this rule only if the outer two have the same colour and width.
    """
    import cv2
    from scipy import ndimage

    n = int(labels.max())
    if n < 3:
        return labels
    idx = np.arange(1, n + 1)
    # thickness: twice the largest distance to another label or the background, in metres
    # (depth holes inside a face are not borders: close them first)
    fgl = labels > 0
    filled = cv2.morphologyEx(fgl.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0
    border = ~filled
    for a, b, sl_a, sl_b in ((labels[:, 1:], labels[:, :-1], np.s_[:, 1:], np.s_[:, :-1]),
                             (labels[1:, :], labels[:-1, :], np.s_[1:, :], np.s_[:-1, :])):
        diff = (a != b) & (a > 0) & (b > 0)
        border[sl_a] |= diff
        border[sl_b] |= diff
    inner = ~border
    dist = cv2.distanceTransform(inner.astype(np.uint8), cv2.DIST_L2, 3)
    # 90th percentile, not the maximum: the centre of a tape cross is wider than its arms
    thick = 2 * np.asarray(ndimage.labeled_comprehension(
        dist * mpp, labels, idx, lambda v: np.percentile(v, 90), float, 0.0), float)
    src = np.where(core, labels, 0)
    cnt = np.maximum(np.asarray(ndimage.sum(np.ones(labels.shape), src, idx)), 1)
    mean = np.stack([np.asarray(ndimage.sum(lab[..., c], src, idx)) / cnt for c in range(3)], axis=1)
    contacts = _contacts(labels)
    nbrs: dict[int, set[int]] = {i: set() for i in idx}
    for (a, b), c in contacts.items():
        if c >= 3:
            nbrs[a].add(b)
            nbrs[b].add(a)
    lut = np.arange(n + 1)
    done: set[int] = set()
    for p in sorted(idx, key=lambda i: thick[i - 1]):
        p = int(p)
        if p in done or thick[p - 1] > cfg.tape_max_m:
            continue
        cand = [q for q in nbrs[p] if q not in done
                and thick[p - 1] <= cfg.tape_rel * thick[q - 1]]
        if len(cand) < 2:
            continue
        best = None
        # the neighbours that share a colour with the largest one of them
        for seed in sorted(cand, key=lambda q: -cnt[q - 1]):
            group = [q for q in cand
                     if np.linalg.norm(mean[q - 1] - mean[seed - 1]) < cfg.tape_colour]
            if len(group) >= 2:
                best = group
                break
        if best is None:
            continue
        # the pieces along the tape's long sides first (not one it only touches with its end)
        side = [q for q in best if contacts[(min(p, q), max(p, q))]
                >= 0.3 * max(contacts[(min(p, r), max(p, r))] for r in best)]
        ok = None
        for group in ([side, best] if len(side) >= 2 and len(side) < len(best) else [best]):
            union = np.isin(labels, [p] + group)
            if _rect_fill(union) >= cfg.rect_fill and _spans(
                    labels == p, union, cfg.tape_span, thick[p - 1] / max(float(np.median(mpp[union])), 1e-6),
                    cfg.tape_frac, cfg.tape_centre):
                ok = group
                break
        if ok is None:
            continue
        best = ok
        for q in best:
            lut[q] = p
            done.add(q)
        done.add(p)
    return lut[labels]


def _spans(piece: np.ndarray, union: np.ndarray, frac: float, thick_px: float = 0.0,
           max_rel: float = 1.0, centre_tol: float = 1.0) -> bool:
    """Whether `piece` looks like tape on the face `union`: it runs across the face along one
    of its rectangle axes (>= `frac` of the face), is thin across that axis (<= `max_rel` of the
    face) and lies near the middle of the face (tape closes the flaps' centre seam)."""
    import cv2

    pts = cv2.findNonZero(piece.astype(np.uint8))
    upts = cv2.findNonZero(union.astype(np.uint8))
    if pts is None or upts is None:
        return False
    (_, _), (_, _), ang = cv2.minAreaRect(pts)
    a = np.deg2rad(ang)
    axes = (np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)]))
    ext = []
    for ax in axes:
        pp = pts.reshape(-1, 2) @ ax
        uu = upts.reshape(-1, 2) @ ax
        ext.append((np.percentile(pp, 1), np.percentile(pp, 99), np.percentile(uu, 1), np.percentile(uu, 99)))
    for i in (0, 1):
        p0, p1, u0, u1 = ext[i]
        if u1 - u0 <= 0 or p1 - p0 < frac * (u1 - u0):
            continue
        q0, q1, v0, v1 = ext[1 - i]
        if v1 - v0 <= 0:
            continue
        width = min(q1 - q0, thick_px) if thick_px > 0 else q1 - q0
        centre = abs(0.5 * (q0 + q1) - 0.5 * (v0 + v1)) / (v1 - v0)
        if width <= max_rel * (v1 - v0) and centre <= centre_tol:
            return True
    return False


def _seam_fraction(labels: np.ndarray, edges: np.ndarray) -> dict[tuple[int, int], float]:
    """(a, b) -> fraction of the border between pieces a and b that runs along a colour edge.

    Two pieces of one face cut apart by a thin tape meet at the tape's middle, away
    from any edge; two boxes meet at their seam, which is an edge line all along.
    """
    n = int(labels.max())
    tot: dict[int, int] = {}
    hit: dict[int, int] = {}
    for a, b, ea, eb in ((labels[:, :-1], labels[:, 1:], edges[:, :-1], edges[:, 1:]),
                         (labels[:-1, :], labels[1:, :], edges[:-1, :], edges[1:, :])):
        sel = (a != b) & (a > 0) & (b > 0)
        if not sel.any():
            continue
        code = np.minimum(a[sel], b[sel]).astype(np.int64) * (n + 1) + np.maximum(a[sel], b[sel])
        e = (ea[sel] | eb[sel]).astype(np.int64)
        u, inv = np.unique(code, return_inverse=True)
        t = np.bincount(inv)
        h = np.bincount(inv, weights=e)
        for k, tt, hh in zip(u, t, h):
            tot[int(k)] = tot.get(int(k), 0) + int(tt)
            hit[int(k)] = hit.get(int(k), 0) + int(hh)
    return {(k // (n + 1), k % (n + 1)): hit[k] / tot[k] for k in tot if tot[k] >= 10}


def _rect_fill(mask: np.ndarray) -> float:
    """How well the mask fills its min-area rectangle: the rectangle of the mask opened by
    5x5 (one-pixel spurs left by growing must not inflate it), depth holes closed."""
    import cv2

    pts = cv2.findNonZero(mask.astype(np.uint8))
    if pts is None:
        return 0.0
    x, y, w, h = cv2.boundingRect(pts)
    sub = np.pad(mask[y:y + h, x:x + w].astype(np.uint8), 3)
    sub = cv2.morphologyEx(sub, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    core = cv2.morphologyEx(sub, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    cpts = cv2.findNonZero(core)
    if cpts is None:
        return 0.0
    rect = cv2.minAreaRect(cpts)
    box = np.zeros_like(sub)
    cv2.fillPoly(box, [np.round(cv2.boxPoints(rect)).astype(np.int32)], 1)
    return float((sub & box).sum()) / max(float(box.sum()), 1.0)


def _finish(merged: np.ndarray, mpp: np.ndarray, cfg: DepthEdgeConfig) -> np.ndarray:
    """Relabel 1..n, dropping faces too small to be a box."""
    from scipy import ndimage

    labels = np.unique(merged)
    labels = labels[labels > 0]
    if len(labels) == 0:
        return np.zeros(merged.shape, np.uint16)
    area = ndimage.sum(mpp * mpp, merged, labels)
    out = np.zeros(merged.shape, np.uint16)
    k = 0
    for lbl, a in zip(labels, area):
        if a < cfg.min_face_m2:
            continue
        k += 1
        out[merged == lbl] = k
    return out
