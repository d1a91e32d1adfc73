"""Cartons in photos without depth: candidate regions from an edge map, carton-shaped ones kept.

With no depth nothing but colour and edges separates two cartons, and the depth-and-edge
segmenter run on a flat stand-in depth leaves big smooth blobs that span several cartons and
the background. This segmenter works on what a carton photo does show (at `work_side` px):
1. an edge map: Lab colour gradient plus thin DARK lines (black-hat: the shadowed seams
   between cartons), normalised per photo but never below an absolute floor (a plain wall's
   noise is no edge);
2. candidate regions, from two sources: the connected low-edge components at several edge
   thresholds (`levels`), each after closing seam gaps of 0-3 px (`gaps`: erode, label,
   dilate back); and every node of a merge tree of watershed superpixels (neighbours joined
   weakest mean border first, small pieces such as printed letters early;
   `perception.photo_tree`);
3. a score per candidate: half shape (its hole-filled mask against its min-area rectangle or
   its convex hull: a face is a quadrilateral, a whole carton seen at an angle a hexagon;
   labels and tape inside a face are holes and are filled), half outline support (the share
   of its outline on an edge: a carton's border is seen, a piece cut out of a face by its
   printing or a patch of wall mostly is not); too small (`min_frac`, the 5th percentile of
   the tune cartons), too large, or spanning the photo border to border (floor, ceiling,
   racks): no candidate;
4. selection, best score first: a candidate that >= 2 disjoint candidates scoring nearly as
   well split (a seam shows at a stricter level: two cartons) is dropped; one that is not
   split takes the small good candidates inside it (labels, print); one mostly covered by
   those already taken is dropped;
5. each kept region is the convex hull of its candidate (cartons are convex), minus pixels
   already taken, scaled back to the photo.
No learned weights; opencv, numpy and scipy. Figures: docs/perception-photos.md.
"""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.photo_config import PhotoConfig
from shelfpick.perception.photo_tree import merge_tree, superpixels

Candidate = tuple[float, tuple[int, int, int, int], np.ndarray]   # score, (y0, x0, y1, x1), mask in that box


def edge_maps(rgb: np.ndarray, cfg: PhotoConfig) -> tuple[np.ndarray, np.ndarray]:
    """(boundary strength, dark-seam strength), both per pixel in [0, 1]: the first is the
    larger of the colour gradient and the seam map."""
    img = cv2.GaussianBlur(rgb, (0, 0), cfg.blur_sigma)
    lab = cv2.cvtColor(img, cv2.COLOR_RGB2LAB).astype(np.float32)
    g2 = np.zeros(lab.shape[:2], np.float32)
    for c, wgt in ((0, 1.0), (1, 2.0), (2, 2.0)):
        gx = cv2.Sobel(lab[..., c], cv2.CV_32F, 1, 0, ksize=3)
        gy = cv2.Sobel(lab[..., c], cv2.CV_32F, 0, 1, ksize=3)
        g2 += wgt * (gx * gx + gy * gy)
    grad = np.sqrt(g2)
    # normalised per photo (contrast varies with light), but never below what counts as a real
    # edge: a plain wall's noise stays weak
    grad /= max(cfg.grad_floor, float(np.percentile(grad, 98)))
    k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (cfg.seam_px, cfg.seam_px))
    seam = cv2.morphologyEx(lab[..., 0], cv2.MORPH_BLACKHAT, k)
    seam /= max(cfg.seam_floor, float(np.percentile(seam, 98)))
    return np.clip(np.maximum(grad, cfg.seam_weight * seam), 0.0, 1.0), np.clip(seam, 0.0, 1.0)


def edge_map(rgb: np.ndarray, cfg: PhotoConfig) -> np.ndarray:
    """Per-pixel boundary strength in [0, 1]: colour gradient plus dark thin seams."""
    return edge_maps(rgb, cfg)[0]


def split_on_lines(mask: np.ndarray, strong: np.ndarray, cfg: PhotoConfig, min_pixels: int = 50,
                   depth: int = 0) -> list[np.ndarray]:
    """Cut `mask` along the straight line of seam pixels (`strong`: dark thin lines; within
    `line_max_deg` of horizontal or vertical) that crosses it most completely, when that line
    is >= `line_cover` on a seam and leaves >= `line_min_part` of the area and at least
    `min_pixels` on each side; then the same for each side.
    Why: cartons stacked flush make one rectangle; the seam between them is a dark straight
    line right across it. Print and labels rarely are, and the edges of a tape band across a
    face are steps of colour, not dark lines."""
    if depth == 0:
        rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
        if len(rows) == 0:
            return [mask]
        y0, y1, x0, x1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
        out = []
        for part in split_on_lines(mask[y0:y1, x0:x1], strong[y0:y1, x0:x1], cfg, min_pixels, 1):
            full = np.zeros_like(mask)
            full[y0:y1, x0:x1] = part
            out.append(full)
        return out
    ys, xs = np.nonzero(mask)
    n = len(ys)
    if n < 2 * min_pixels or depth > 8:
        return [mask]
    on = strong[ys, xs]
    best = None
    for axis in (0, 1):
        u, v = (ys, xs) if axis == 0 else (xs, ys)       # cut across u = const (+ tilt)
        vc = float(v.mean())
        for deg in np.arange(-cfg.line_max_deg, cfg.line_max_deg + 1e-6, 2.0):
            t = np.tan(np.radians(deg))
            b = np.round(u - t * (v - vc)).astype(np.int64)
            b0 = int(b.min())
            b = b - b0
            tot = np.bincount(b)
            hit = np.bincount(b, weights=on)
            # a seam is 1-3 px wide: take the best of 3 neighbouring bins
            pad = np.pad(hit, 1)
            hit3 = np.maximum(np.maximum(pad[:-2], pad[1:-1]), pad[2:])
            length = np.maximum(tot, 1)
            frac = hit3 / length
            cum = np.cumsum(tot) / n
            least = max(cfg.line_min_part, min_pixels / n)
            ok = (cum >= least) & (cum <= 1.0 - least) & (tot >= 10)
            if not ok.any():
                continue
            k = int(np.argmax(np.where(ok, frac, -1)))
            k = max(0, k - 1) + int(np.argmax(hit[max(0, k - 1):k + 2]))   # onto the seam itself
            if frac[k] >= cfg.line_cover and (best is None or frac[k] > best[0]):
                best = (float(frac[k]), axis, float(t), vc, k + b0)
    if best is None:
        return [mask]
    _, axis, t, vc, cut = best
    yy, xx = np.indices(mask.shape)
    u, v = (yy, xx) if axis == 0 else (xx, yy)
    side = np.round(u - t * (v - vc)) <= cut
    out = []
    for part in (mask & side, mask & ~side):
        out.extend(split_on_lines(part, strong, cfg, min_pixels, depth + 1))
    return out


class PhotoSegmenter:
    """Carton masks in an RGB photo (depth ignored); see the module docstring."""

    name = "photo"

    def __init__(self, config: PhotoConfig | None = None):
        self.config = config or PhotoConfig()

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None = None) -> list[np.ndarray]:
        """One HxW bool mask per carton found, disjoint; `depth` is not used."""
        cfg = self.config
        rgb = np.asarray(rgb)
        if rgb.ndim == 2:
            rgb = np.repeat(rgb[..., None], 3, axis=2)
        rgb = rgb[..., :3]
        if rgb.dtype != np.uint8:
            rgb = np.clip(rgb, 0, 255).astype(np.uint8)
        H, W = rgb.shape[:2]
        s = min(1.0, cfg.work_side / max(H, W))
        small = cv2.resize(rgb, (max(1, round(W * s)), max(1, round(H * s))),
                           interpolation=cv2.INTER_AREA) if s < 1.0 else rgb
        out = []
        for m in self.regions(small):
            if s < 1.0:
                m = cv2.resize(m.astype(np.uint8) * 255, (W, H), interpolation=cv2.INTER_LINEAR) > 127
            if m.any():
                out.append(m)
        return out

    def regions(self, rgb: np.ndarray) -> list[np.ndarray]:
        """Kept regions at the size of `rgb` (the work size)."""
        cfg = self.config
        edges, seams = edge_maps(rgb, cfg)
        cands = self.candidates(edges)
        if cfg.tree:
            cands += self.tree_candidates(rgb, edges)
        kept = self._select(self.rescore(cands, edges), edges.shape)
        if cfg.split_lines:
            on_seam = seams >= cfg.line_edge
            least = int(cfg.min_frac * edges.size)
            kept = [p for m in kept for p in split_on_lines(m, on_seam, cfg, least)]
        return kept

    def rescore(self, cands: list[Candidate], edges: np.ndarray) -> list[Candidate]:
        """Score = half shape quality, half outline support: the share of the region's outline
        that runs along an edge (a seam or a carton's border against the background); a piece
        cut out of one face by its printing, or a patch of wall, has less."""
        cfg = self.config
        strong = cv2.dilate((edges >= cfg.support_edge).astype(np.uint8), np.ones((5, 5), np.uint8))
        out = []
        for q, (y0, x0, y1, x1), f in cands:
            cnts, _ = cv2.findContours(f.astype(np.uint8), cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_NONE)
            if not cnts:
                continue
            pts = np.concatenate(cnts)[:, 0, :]
            sub = strong[y0:y1, x0:x1]
            support = float(sub[pts[:, 1], pts[:, 0]].mean())
            if support < cfg.min_support:     # a carton's outline is seen: a seam or its border
                continue
            out.append(((1 - cfg.support_weight) * q + cfg.support_weight * support, (y0, x0, y1, x1), f))
        return out

    def tree_candidates(self, rgb: np.ndarray, edges: np.ndarray) -> list[Candidate]:
        """(quality, bbox, mask in bbox) of every node of the superpixel merge tree."""
        cfg = self.config
        h, w = edges.shape
        total = h * w
        lab = superpixels(edges, cfg.seed_px)
        nodes = merge_tree(rgb, lab, edges, cfg)
        nl = int(lab.max()) + 1
        out = []
        for nd in nodes:
            if not cfg.min_frac * total <= nd.area <= cfg.max_frac * total:
                continue
            y0, x0, y1, x1 = nd.bbox
            if (x0 <= 1 and x1 >= w - 1) or (y0 <= 1 and y1 >= h - 1):
                continue
            lut = np.zeros(nl, np.uint8)
            lut[nd.leaves] = 1
            c = self._quality(lut[lab[y0:y1, x0:x1]])
            if c is not None:
                out.append((c[0], (y0, x0, y1, x1), c[1]))
        return out

    def candidates(self, edges: np.ndarray) -> list[Candidate]:
        """(quality, bbox, filled mask in bbox) of every low-edge component at every level."""
        cfg = self.config
        h, w = edges.shape
        total = h * w
        out = []
        for t in cfg.levels:
            low = (edges < t).astype(np.uint8)
            for d in cfg.gaps:
                k = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * d + 1, 2 * d + 1))
                core = cv2.erode(low, k) if d else low
                n, lab, st, _ = cv2.connectedComponentsWithStats(core, connectivity=4)
                for i in range(1, n):
                    x0, y0, bw, bh, a = (int(v) for v in st[i])
                    if a < cfg.min_frac * total * 0.5 or a > cfg.max_frac * total:
                        continue
                    x1, y1 = x0 + bw, y0 + bh
                    if (x0 <= 1 and x1 >= w - 1) or (y0 <= 1 and y1 >= h - 1):
                        continue
                    pad = d + 1
                    X0, Y0 = max(0, x0 - pad), max(0, y0 - pad)
                    X1, Y1 = min(w, x1 + pad), min(h, y1 + pad)
                    m = (lab[Y0:Y1, X0:X1] == i).astype(np.uint8)
                    if d:
                        m = cv2.dilate(m, k)
                    c = self._quality(m)
                    if c is None:
                        continue
                    q, filled = c
                    if filled.sum() < cfg.min_frac * total:
                        continue
                    out.append((q, (Y0, X0, Y1, X1), filled))
        return out

    @staticmethod
    def _quality(m: np.ndarray) -> tuple[float, np.ndarray] | None:
        """How much the hole-filled region looks like one carton: its IoU with its min-area
        rectangle, and with its convex hull (a whole carton seen at an angle); and the hull,
        the mask the region is kept as."""
        cnts, _ = cv2.findContours(m, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
        if not cnts:
            return None
        cnt = max(cnts, key=cv2.contourArea)
        filled = np.zeros_like(m)
        cv2.drawContours(filled, [cnt], -1, 1, -1)
        fa = float(filled.sum())
        if fa < 4:
            return None
        rect = np.zeros_like(m)
        cv2.fillPoly(rect, [np.round(cv2.boxPoints(cv2.minAreaRect(cnt))).astype(np.int32)], 1)
        inter = float(np.logical_and(rect, filled).sum())
        q_rect = inter / (fa + float(rect.sum()) - inter)
        hull = cv2.convexHull(cnt)
        q_hull = fa / max(fa, float(cv2.contourArea(hull)) + 0.5 * cv2.arcLength(hull, True))
        hm = np.zeros_like(m)
        cv2.fillPoly(hm, [hull], 1)
        return max(q_rect, q_hull - 0.05), hm > 0

    def _select(self, cands: list[Candidate], shape: tuple[int, int]) -> list[np.ndarray]:
        """Best score first; a candidate that two or more good candidates split (a seam shows at
        a stricter level) is dropped, a good one that is not split takes the small ones inside
        it (labels, tape, print), and one mostly covered by those already taken is dropped."""
        cfg = self.config
        h, w = shape
        good, seen = [], set()
        for c in sorted((c for c in cands if c[0] >= cfg.q0), key=lambda c: -c[0]):
            key = (c[1], int(c[2].sum()))                 # the same region from several levels
            if key not in seen:
                seen.add(key)
                good.append(c)
        if not good:
            return []
        q = np.array([c[0] for c in good])
        bb = np.array([c[1] for c in good])
        areas = np.array([float(c[2].sum()) for c in good])
        split = np.array([self._is_split(i, good, q, bb, areas) for i in range(len(good))], bool)
        for i in np.argsort(-areas, kind="stable"):
            if split[i]:
                continue
            y0, x0 = int(bb[i][0]), int(bb[i][1])
            f = good[i][2]
            for j in self._inside(i, bb, areas, ~split & (areas < cfg.nest_max * areas[i])):
                Y0, X0, Y1, X1 = (int(v) for v in bb[j])
                if float(np.logical_and(f[Y0 - y0:Y1 - y0, X0 - x0:X1 - x0], good[j][2]).sum()) >= 0.85 * areas[j]:
                    split[j] = True
        taken = np.zeros((h, w), bool)
        out = []
        for i, (_, (y0, x0, y1, x1), f) in enumerate(good):
            if split[i]:
                continue
            if float(np.logical_and(taken[y0:y1, x0:x1], f).sum()) > cfg.max_overlap * areas[i]:
                continue
            full = np.zeros((h, w), bool)
            full[y0:y1, x0:x1] = f & ~taken[y0:y1, x0:x1]
            taken |= full
            out.append(full)
        return out

    @staticmethod
    def _inside(i: int, bb: np.ndarray, areas: np.ndarray, allowed: np.ndarray) -> list[int]:
        """Candidates (among `allowed`) whose bounding box lies in i's."""
        y0, x0, y1, x1 = bb[i]
        sel = allowed & (bb[:, 0] >= y0) & (bb[:, 1] >= x0) & (bb[:, 2] <= y1) & (bb[:, 3] <= x1)
        sel[i] = False
        return [int(j) for j in np.nonzero(sel)[0]]

    def _is_split(self, i: int, good, q: np.ndarray, bb: np.ndarray, areas: np.ndarray) -> bool:
        """Whether >= 2 disjoint good candidates, each scoring nearly as well, lie inside
        candidate i and cover most of it."""
        cfg = self.config
        allowed = ((areas < 0.9 * areas[i]) & (areas >= cfg.split_min_part * areas[i])
                   & (q >= q[i] - cfg.split_margin))
        if allowed.sum() < 2:
            return False
        y0, x0 = int(bb[i][0]), int(bb[i][1])
        f = good[i][2]
        cover = np.zeros(f.shape, bool)
        n_parts = 0
        for j in self._inside(i, bb, areas, allowed):    # best first: `good` is sorted
            Y0, X0, Y1, X1 = (int(v) for v in bb[j])
            g = good[j][2]
            if float(np.logical_and(f[Y0 - y0:Y1 - y0, X0 - x0:X1 - x0], g).sum()) < 0.85 * areas[j]:
                continue
            sub = cover[Y0 - y0:Y1 - y0, X0 - x0:X1 - x0]
            if float(np.logical_and(sub, g).sum()) > 0.2 * areas[j]:
                continue
            sub |= g
            n_parts += 1
        return n_parts >= 2 and float(np.logical_and(cover, f).sum()) >= cfg.split_cover * areas[i]
