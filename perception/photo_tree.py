"""The photo segmenter's second source of candidate regions: a merge tree of superpixels.

Watershed superpixels of the edge map (one seed per cell) are joined pairwise, weakest
border first (mean edge strength along it plus the mean-colour difference; pieces below
`small_frac` of the photo first, so printed letters join their face early), up to one
region; every join is a node, and every node a candidate. Used by
`perception.segment_photo.PhotoSegmenter.tree_candidates`.
"""
from __future__ import annotations

import heapq
from dataclasses import dataclass
import cv2
import numpy as np
from scipy import ndimage

from shelfpick.perception.photo_config import PhotoConfig


@dataclass(frozen=True)
class Node:
    """A region of the superpixel merge tree."""

    area: int
    bbox: tuple[int, int, int, int]       # y0, x0, y1, x1 (exclusive)
    leaves: list[int]


def superpixels(edges: np.ndarray, spacing: int) -> np.ndarray:
    """Watershed of the edge map from one seed per `spacing` cell (at the cell's weakest edge)."""
    h, w = edges.shape
    markers = np.zeros((h, w), np.int32)
    n = 0
    for y0 in range(0, h, spacing):
        for x0 in range(0, w, spacing):
            cell = edges[y0:y0 + spacing, x0:x0 + spacing]
            iy, ix = np.unravel_index(int(np.argmin(cell)), cell.shape)
            n += 1
            markers[y0 + iy, x0 + ix] = n
    lab = ndimage.watershed_ift((edges * 255).astype(np.uint8), markers)
    return lab.astype(np.int32) - 1


def _adjacency(lab: np.ndarray, edges: np.ndarray, n: int) -> dict[tuple[int, int], tuple[float, int]]:
    """(a, b) with a < b -> (sum of edge strength along their border, border length)."""
    pa = [lab[:, :-1].ravel(), lab[:-1, :].ravel()]
    pb = [lab[:, 1:].ravel(), lab[1:, :].ravel()]
    ps = [np.maximum(edges[:, :-1], edges[:, 1:]).ravel(), np.maximum(edges[:-1, :], edges[1:, :]).ravel()]
    a = np.concatenate(pa)
    b = np.concatenate(pb)
    s = np.concatenate(ps)
    keep = a != b
    a, b, s = a[keep], b[keep], s[keep]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    code = lo.astype(np.int64) * n + hi
    uniq, inv = np.unique(code, return_inverse=True)
    sums = np.bincount(inv, weights=s)
    cnts = np.bincount(inv)
    return {(int(c // n), int(c % n)): (float(sm), int(ct)) for c, sm, ct in zip(uniq, sums, cnts)}


def _leaf_nodes(lab: np.ndarray, n: int) -> list[Node]:
    """One node per superpixel: its area and bounding box."""
    h, w = lab.shape
    flat = lab.ravel()
    area = np.bincount(flat, minlength=n).astype(np.int64)
    ys, xs = np.indices((h, w))
    y0 = np.full(n, h, np.int64)
    x0 = np.full(n, w, np.int64)
    y1 = np.zeros(n, np.int64)
    x1 = np.zeros(n, np.int64)
    np.minimum.at(y0, flat, ys.ravel())
    np.minimum.at(x0, flat, xs.ravel())
    np.maximum.at(y1, flat, ys.ravel() + 1)
    np.maximum.at(x1, flat, xs.ravel() + 1)
    return [Node(int(area[i]), (int(y0[i]), int(x0[i]), int(y1[i]), int(x1[i])), [i]) for i in range(n)]


class _Tree:
    """The merge tree while it is built: its nodes, their Lab colour sums, each root's
    neighbours ([edge strength summed along the border, border length]) and which nodes are
    roots still."""

    def __init__(self, nodes: list[Node], colsum: list[np.ndarray], nbr: list[dict[int, list[float]]],
                 small: float, colour_weight: float):
        self.nodes, self.colsum, self.nbr = nodes, colsum, nbr
        self.small, self.colour_weight = small, colour_weight
        self.alive = [True] * len(nodes)

    def prio(self, a: int, b: int) -> float:
        """How weak the border between roots a and b is (lower joins first)."""
        sm, ct = self.nbr[a][b]
        ca = self.colsum[a] / self.nodes[a].area
        cb = self.colsum[b] / self.nodes[b].area
        dc = float(np.linalg.norm(ca - cb)) / 100.0
        p = sm / ct + self.colour_weight * dc
        return p * min(1.0, min(self.nodes[a].area, self.nodes[b].area) / self.small) ** 0.5

    def join(self, a: int, b: int) -> int:
        """Roots a and b joined into a new root; its index."""
        na, nb = self.nodes[a], self.nodes[b]
        c = len(self.nodes)
        bb = (min(na.bbox[0], nb.bbox[0]), min(na.bbox[1], nb.bbox[1]),
              max(na.bbox[2], nb.bbox[2]), max(na.bbox[3], nb.bbox[3]))
        self.nodes.append(Node(na.area + nb.area, bb, na.leaves + nb.leaves))
        self.colsum.append(self.colsum[a] + self.colsum[b])
        self.alive[a] = self.alive[b] = False
        self.alive.append(True)
        merged: dict[int, list[float]] = {}
        for src in (a, b):
            for k, (s_, c_) in self.nbr[src].items():
                if k in (a, b):
                    continue
                e = merged.setdefault(k, [0.0, 0])
                e[0] += s_
                e[1] += c_
                del self.nbr[k][src]
        self.nbr.append(merged)
        self.nbr[a] = {}
        self.nbr[b] = {}
        for k, e in merged.items():
            self.nbr[k][c] = e
        return c


def merge_tree(rgb: np.ndarray, lab: np.ndarray, edges: np.ndarray, cfg: PhotoConfig) -> list[Node]:
    """Superpixels (`lab`) joined pairwise, weakest border first (mean edge strength along it
    plus the mean-colour difference; pieces below `small_frac` of the photo first), up to one
    region: every join is a node."""
    h, w = lab.shape
    n = int(lab.max()) + 1
    flat = lab.ravel()
    col = cv2.cvtColor(cv2.GaussianBlur(rgb, (0, 0), cfg.blur_sigma), cv2.COLOR_RGB2LAB).astype(np.float64)
    csum = np.stack([np.bincount(flat, weights=col[..., c].ravel(), minlength=n) for c in range(3)], 1)
    nbr: list[dict[int, list[float]]] = [dict() for _ in range(n)]
    for (a, b), (sm, ct) in _adjacency(lab, edges, n).items():
        nbr[a][b] = [sm, ct]
        nbr[b][a] = [sm, ct]
    tree = _Tree(_leaf_nodes(lab, n), [csum[i] for i in range(n)], nbr, cfg.small_frac * h * w,
                 cfg.colour_weight)
    heap = [(tree.prio(a, b), a, b) for a in range(n) for b in nbr[a] if a < b]
    heapq.heapify(heap)
    while heap:
        _, a, b = heapq.heappop(heap)
        if not (tree.alive[a] and tree.alive[b]):
            continue
        c = tree.join(a, b)
        for k in tree.nbr[c]:
            heapq.heappush(heap, (tree.prio(c, k), c, k) if c < k else (tree.prio(k, c), k, c))
    return tree.nodes
