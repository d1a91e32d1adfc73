"""Cartons of one printed design side by side or stacked in one mask, cut where the print repeats
(issue 31, the `labels` tuning look).

Flush cartons of one print at one depth are separated only by a thin seam (often none in the
image) and by the repeat of their print: a design printed on every carton is laid out on each
face in proportion to that face, so the two parts of a mask that is two cartons look alike once
each is scaled to a unit face, and a mask that is one carton does not (its top half is not its
bottom half). Along the axis of a candidate cut the mask is reduced to a profile (mean CIELAB in
`STRIPS` strips across it, per image row or column); each candidate partition (two parts at any
cut, or 2-4 equal parts) is scored by how alike its parts' profiles are after each is resampled
to `SAMPLES` points (1 = the same print, about 0 = unrelated), against the profile's own spread
(a plain face or one band running along the axis has no profile to repeat and is never cut).
A cut is kept only when the score beats `MIN_SCORE`, the same partition shifted by a sixth of a
part scores clearly worse (`MIN_PEAK`: a repeat, not a texture that looks alike everywhere), and
the caller finds every part a box front. No catalogue, no depth condition.
"""
from __future__ import annotations

import numpy as np

STRIPS = 3              # strips across the profile axis (a label on one side is still seen)
SAMPLES = 24            # a part's profile resampled to this many points
MIN_SPREAD = 6.0        # CIELAB std of a part's profile below which it has no print to repeat
MIN_SCORE = 0.6         # parts this alike are the same print (one carton's halves: <= 0.4 on the tuning look)
MIN_PEAK = 0.1          # ... and the partition shifted by a sixth of a part is this much less alike
MIN_PART_PX = 12        # a part spans at least this many rows (columns)
L_WEIGHT = 0.5          # lightness counts half: a hard shadow changes it, not the print's hue


def profile(mask: np.ndarray, lab: np.ndarray, axis: int) -> tuple[int, np.ndarray]:
    """(first index, P x STRIPS*3 profile) of the mask along `axis` (0: per image row, 1: per
    column); rows with no mask pixel are filled from their neighbours."""
    m = mask if axis == 0 else mask.T
    im = lab if axis == 0 else lab.transpose(1, 0, 2)
    width = m.sum(axis=1)
    idx = np.flatnonzero(width >= 0.5 * np.median(width[width > 0]))   # slivers (a top face) left out
    lo, hi = int(idx[0]), int(idx[-1]) + 1
    cols = np.flatnonzero(m.any(axis=0))
    edges = np.linspace(cols[0], cols[-1] + 1, STRIPS + 1).astype(int)
    out = np.full((hi - lo, STRIPS, 3), np.nan)
    for s in range(STRIPS):
        sub_m = m[lo:hi, edges[s]:edges[s + 1]]
        sub = im[lo:hi, edges[s]:edges[s + 1]]
        n = sub_m.sum(axis=1)
        tot = (sub * sub_m[..., None]).sum(axis=1)
        ok = n >= 2
        out[ok, s] = tot[ok] / n[ok, None]
    out[..., 0] *= L_WEIGHT
    flat = out.reshape(hi - lo, -1)
    for c in range(flat.shape[1]):
        col = flat[:, c]
        bad = np.isnan(col)
        if bad.all():
            flat[:, c] = 0.0
        elif bad.any():
            col[bad] = np.interp(np.flatnonzero(bad), np.flatnonzero(~bad), col[~bad])
    return lo, flat


def _resampled(prof: np.ndarray, a: float, b: float) -> np.ndarray:
    x = np.clip(np.linspace(a, b - 1, SAMPLES), 0, len(prof) - 1)
    i = np.minimum(x.astype(int), len(prof) - 2) if len(prof) > 1 else np.zeros(SAMPLES, int)
    w = (x - i)[:, None] if len(prof) > 1 else np.zeros((SAMPLES, 1))
    return prof[i] * (1 - w) + prof[np.minimum(i + 1, len(prof) - 1)] * w


def _alike_two(prof: np.ndarray, cs: np.ndarray) -> np.ndarray:
    """`alike(prof, [0, c, n])` for every cut c in `cs` at once."""
    n = len(prof)
    t = np.linspace(0.0, 1.0, SAMPLES)

    def gather(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        x = np.clip(a[:, None] + (b - 1 - a)[:, None] * t, 0, n - 1)
        i = np.minimum(x.astype(int), max(n - 2, 0))
        w = (x - i)[..., None]
        return prof[i] * (1 - w) + prof[np.minimum(i + 1, n - 1)] * w

    p, q = gather(np.zeros_like(cs), cs), gather(cs, np.full_like(cs, n))
    sp = ((p - p.mean(1, keepdims=True)) ** 2).sum(2).mean(1)
    sq = ((q - q.mean(1, keepdims=True)) ** 2).sum(2).mean(1)
    out = 1 - ((p - q) ** 2).sum(2).mean(1) / np.maximum(sp + sq, 1e-9)
    return np.where(np.minimum(sp, sq) < MIN_SPREAD ** 2, -1.0, out)


def alike(prof: np.ndarray, cuts: list[float]) -> float:
    """How alike the parts between `cuts` (profile indices, ends included) are, each scaled to
    SAMPLES points: 1 - mean squared difference of consecutive parts over twice their spread;
    -1 when a part has no print (spread under MIN_SPREAD)."""
    parts = [_resampled(prof, a, b) for a, b in zip(cuts[:-1], cuts[1:])]
    spread = [float(((p - p.mean(0)) ** 2).sum(1).mean()) for p in parts]
    if min(spread) < MIN_SPREAD ** 2:
        return -1.0
    scores = [1 - float(((p - q) ** 2).sum(1).mean()) / (sp + sq)
              for p, q, sp, sq in zip(parts[:-1], parts[1:], spread[:-1], spread[1:])]
    return min(scores)


def best_partition(prof: np.ndarray) -> tuple[float, float, list[float]]:
    """(score, score of the same partition shifted, cuts) of the best-scoring partition of a
    profile: two parts at any cut (each >= 20% and >= MIN_PART_PX), or k = 2..4 equal parts."""
    n = len(prof)
    best: tuple[float, float, list[float]] = (-1.0, -1.0, [0.0, float(n)])
    if float(((prof - prof.mean(0)) ** 2).sum(1).mean()) < MIN_SPREAD ** 2:
        return best                                   # no print along this axis (a plain face)
    lo, hi = max(MIN_PART_PX, int(0.2 * n)), min(n - MIN_PART_PX, int(0.8 * n))
    step = max(1, n // 24)                            # coarse cuts, then every row around the best
    cs = np.arange(lo, hi + 1, step, dtype=float)
    if len(cs):
        sc = _alike_two(prof, cs)
        j = int(np.argmax(sc))
        best = (float(sc[j]), 0.0, [0.0, float(cs[j]), float(n)])
    for cuts in ([n * j / k for j in range(k + 1)] for k in (3, 4) if n / k >= MIN_PART_PX):
        s = alike(prof, cuts)
        if s > best[0]:
            best = (s, 0.0, cuts)
    if len(best[2]) == 3 and step > 1:
        c0 = int(best[2][1])
        cs = np.arange(max(lo, c0 - step + 1), min(hi, c0 + step - 1) + 1, dtype=float)
        sc = _alike_two(prof, cs)
        j = int(np.argmax(sc))
        if sc[j] > best[0]:
            best = (float(sc[j]), 0.0, [0.0, float(cs[j]), float(n)])
    if best[0] < 0:
        return best
    cuts = best[2]
    part = min(b - a for a, b in zip(cuts[:-1], cuts[1:]))
    d = part / 6
    shifted = []
    for sign in (-1, 1):
        inner = [c + sign * d for c in cuts[1:-1]]
        if len(cuts) == 3:        # one cut: shift the cut
            shifted.append(alike(prof, [0.0, *inner, float(n)]))
        else:                     # equal parts: shift every inner cut
            shifted.append(alike(prof, [0.0, *inner, float(n)]))
    return best[0], max(shifted), cuts


def repeat_parts(mask: np.ndarray, lab: np.ndarray) -> tuple[list[np.ndarray], int, float]:
    """(parts, axis, score): the mask cut where its print repeats, along image rows (axis 0:
    stacked) or columns (axis 1: side by side), the better of the two; ([mask], -1, score) when
    no partition passes MIN_SCORE and MIN_PEAK."""
    found: tuple[float, int, list[float], int] = (-1.0, -1, [], 0)
    for axis in (0, 1):
        m = mask if axis == 0 else mask.T
        if m.any(axis=1).sum() < 2 * MIN_PART_PX:
            continue
        lo, prof = profile(mask, lab, axis)
        s, shifted, cuts = best_partition(prof)
        if s >= MIN_SCORE and s - shifted >= MIN_PEAK and s > found[0]:
            found = (s, axis, cuts, lo)
    s, axis, cuts, lo = found
    if axis < 0:
        return [mask], -1, s
    parts = []
    grid = np.arange(mask.shape[axis])
    for a, b in zip(cuts[:-1], cuts[1:]):
        sel = (grid >= lo + round(a)) & (grid < lo + round(b))
        parts.append(mask & (sel[:, None] if axis == 0 else sel[None, :]))
    return parts, axis, s
