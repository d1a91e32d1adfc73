"""Matching predicted masks to true ones by IoU: how the benchmarks score a segmentation, and how
the learned segmenter keeps the rule masks it agrees with."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.pixels import count


def mask_iou(a: np.ndarray, b: np.ndarray) -> float:
    u = count(np.logical_or(a, b))
    return float(count(np.logical_and(a, b))) / float(u) if u else 0.0


def match(pred: list[np.ndarray], truth: list[np.ndarray], thr: float = 0.5) -> list[tuple[int, int, float]]:
    """Greedy one-to-one matching by IoU: (truth index, pred index, IoU) for IoU >= thr."""
    cands = []
    for i, g in enumerate(truth):
        for j, p in enumerate(pred):
            if np.logical_and(g, p).any():
                v = mask_iou(g, p)
                if v >= thr:
                    cands.append((v, i, j))
    cands.sort(reverse=True)
    used_t, used_p, out = set(), set(), []
    for v, i, j in cands:
        if i in used_t or j in used_p:
            continue
        used_t.add(i)
        used_p.add(j)
        out.append((i, j, v))
    return out
