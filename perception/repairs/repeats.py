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
the caller finds every part a box front at least `REPEAT_MIN_SIDE` on each side. No catalogue,
no depth condition.
"""
from __future__ import annotations

import numpy as np

from shelfpick.perception.pixels import nonzero

STRIPS = 3              # strips across the profile axis (a label on one side is still seen)
SAMPLES = 24            # a part's profile resampled to this many points
MIN_SPREAD = 6.0        # CIELAB std of a part's profile below which it has no print to repeat
MIN_SCORE = 0.6         # parts this alike are the same print (one carton's halves: <= 0.4 on the tuning look)
MIN_PEAK = 0.1          # ... and the partition shifted by a sixth of a part is this much less alike
MIN_PART_PX = 12        # a part spans at least this many rows (columns)
REPEAT_MIN_SIDE = 0.10  # m: every part a carton front at least this wide and high (a cut leaving a 6 cm
#                         strip of one face was made on two of our own renders)
L_WEIGHT = 0.5          # lightness counts half: a hard shadow changes it, not the print's hue
_T = np.linspace(0.0, 1.0, SAMPLES)     # where a part's samples lie, 0 (its start) to 1 (its end)


def profile(mask: np.ndarray, lab: np.ndarray, axis: int) -> tuple[int, np.ndarray]:
    """(first index, P x STRIPS*3 profile) of the mask along `axis` (0: per image row, 1: per
    column); rows with no mask pixel are filled from their neighbours. Each row's strips divide
    that row's own extent, not the mask's bounding box: a print sits where it sits on its own
    carton, and the cartons of a stack are seldom aligned in the image (a column seen at an
    angle, a carton pushed in; labels 31028's stack of four was never cut on box strips)."""
    m = mask if axis == 0 else np.ascontiguousarray(mask.T)
    width = m.sum(axis=1)
    idx = np.flatnonzero(width >= 0.5 * np.median(width[width > 0]))   # slivers (a top face) left out
    lo, hi = int(idx[0]), int(idx[-1]) + 1
    sub = m[lo:hi]
    first = np.argmax(sub, axis=1)
    span = np.maximum(sub.shape[1] - np.argmax(sub[:, ::-1], axis=1) - first, 1)
    rr, cc = nonzero(sub)
    key = rr * STRIPS + np.minimum((cc - first.take(rr)) * STRIPS // span.take(rr), STRIPS - 1)
    nb = (hi - lo) * STRIPS
    n = np.bincount(key, minlength=nb).reshape(hi - lo, STRIPS).astype(float)
    at = (rr + lo) * mask.shape[1] + cc if axis == 0 else cc * mask.shape[1] + rr + lo
    vals = _pixels(lab).take(at, axis=0)           # = (lab or its transpose)[lo:hi][rr, cc]
    tot = np.stack([np.bincount(key, weights=vals[:, k], minlength=nb) for k in range(3)], -1)
    out = np.where((n >= 2)[..., None], tot.reshape(hi - lo, STRIPS, 3) / np.maximum(n, 1)[..., None], np.nan)
    out[..., 0] *= L_WEIGHT
    flat = out.reshape(hi - lo, -1)
    nan = np.isnan(flat)
    for c in np.flatnonzero(nan.any(axis=0)):       # the columns with a gap
        col, bad = flat[:, c], nan[:, c]
        if bad.all():
            flat[:, c] = 0.0
        else:
            col[bad] = np.interp(np.flatnonzero(bad), np.flatnonzero(~bad), col[~bad])
    return lo, flat


def _pixels(lab: np.ndarray) -> np.ndarray:
    """The image's pixels as rows of an (H*W) x 3 array (a view when it is contiguous)."""
    return np.ascontiguousarray(lab).reshape(-1, lab.shape[-1])


def _resampled(prof: np.ndarray, a: float, b: float) -> np.ndarray:
    x = np.clip(np.linspace(a, b - 1, SAMPLES), 0, len(prof) - 1)
    i = np.minimum(x.astype(int), len(prof) - 2) if len(prof) > 1 else np.zeros(SAMPLES, int)
    w = (x - i)[:, None] if len(prof) > 1 else np.zeros((SAMPLES, 1))
    return prof[i] * (1 - w) + prof[np.minimum(i + 1, len(prof) - 1)] * w


def _alike_two(prof: np.ndarray, a: np.ndarray, c: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`alike(prof, [a, c, b])` for every row of the arrays a, c, b at once (the first parts and
    the second ones resampled, and their spreads taken, in one go: a row's numbers are its own)."""
    n, k = len(prof), len(a)
    lo, hi = np.concatenate([a, c]), np.concatenate([c, b])
    x = np.clip(lo[:, None] + (hi - 1 - lo)[:, None] * _T, 0, n - 1)
    i = np.minimum(x.astype(int), max(n - 2, 0))
    w = (x - i)[..., None]
    parts = prof[i] * (1 - w) + prof[np.minimum(i + 1, n - 1)] * w
    spread = ((parts - parts.mean(1, keepdims=True)) ** 2).sum(2).mean(1)
    p, q, sp, sq = parts[:k], parts[k:], spread[:k], spread[k:]
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


def _windows(n: int, cs: np.ndarray, kind: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(a, c, b) of two-part windows at cuts `cs`: kind 0 the whole profile [0, c, n]; kind 1
    the first part and as much again [0, c, 2c] (a stack of three or more); kind 2 the same
    from the far end [n - 2(n - c), c, n]."""
    z, e = np.zeros_like(cs), np.full_like(cs, float(n))
    if kind == 0:
        return z, cs, e
    if kind == 1:
        return z, cs, 2 * cs
    return 2 * cs - n, cs, e


def _coarse(prof: np.ndarray, ranges: tuple[tuple[int, int], ...], step: int) -> tuple[float, int, float]:
    """(score, kind, cut) of the best coarse cut of each kind's range (the first kind's on a tie),
    (-1, 0, 0) when none scores above -1: all kinds' windows scored by one `_alike_two` (a
    window's score depends on its own row only, so it is the one it gets alone)."""
    n = len(prof)
    cuts = [np.arange(lo, hi + 1, step, dtype=float) for lo, hi in ranges]
    wins = [_windows(n, cs, kind) for kind, cs in enumerate(cuts)]
    sc = _alike_two(prof, *(np.concatenate(w) for w in zip(*wins)))
    best, start = (-1.0, 0, 0.0), 0
    for kind, cs in enumerate(cuts):
        part = sc[start:start + len(cs)]
        start += len(cs)
        if len(cs):
            j = int(np.argmax(part))
            if part[j] > best[0]:
                best = (float(part[j]), kind, float(cs[j]))
    return best


def best_cut(prof: np.ndarray) -> tuple[float, float, float]:
    """(score, score with the cut moved by a sixth of the shorter part, cut): the cut whose two
    sides look most alike, each side scaled to a unit face: the whole profile's two parts
    (each >= 20%), or the first (last) part against the next one of the same length (a stack of
    three or more cartons: the rest is cut again by the caller)."""
    n = len(prof)
    if n < 2 * MIN_PART_PX or float(((prof - prof.mean(0)) ** 2).sum(1).mean()) < MIN_SPREAD ** 2:
        return -1.0, -1.0, 0.0                        # no print along this axis (a plain face)
    ranges = ((max(MIN_PART_PX, int(0.2 * n)), min(n - MIN_PART_PX, int(0.8 * n))),
              (MIN_PART_PX, n // 2 - 1), (n - n // 2 + 1, n - MIN_PART_PX))
    step = max(1, n // 24)                            # coarse cuts, then every row around the best
    score, kind, c0 = _coarse(prof, ranges, step)
    if score < 0:
        return -1.0, -1.0, 0.0
    lo, hi = ranges[kind]
    cs = np.arange(max(lo, int(c0) - step + 1), min(hi, int(c0) + step - 1) + 1, dtype=float)
    sc = _alike_two(prof, *_windows(n, cs, kind))
    j = int(np.argmax(sc))
    if sc[j] > score:
        score, c0 = float(sc[j]), float(cs[j])
    a, _, b = (float(v[0]) for v in _windows(n, np.array([c0]), kind))
    d = min(c0 - a, b - c0) / 6
    moved = np.array([c0 - d, c0 + d])
    if kind == 0:
        shifted = _alike_two(prof, np.zeros(2), moved, np.full(2, float(n)))
    else:
        shifted = _alike_two(prof, *_windows(n, moved, kind))
    return score, float(shifted.max()), c0


def repeat_parts(mask: np.ndarray, lab: np.ndarray, depth: int = 3) -> tuple[list[np.ndarray], int, float]:
    """(parts, axis, score): the mask cut where its print repeats, along image rows (axis 0:
    stacked) or columns (axis 1: side by side), the better of the two, each part cut again (up to
    `depth` cuts deep: a stack of four); ([mask], -1, score) when no cut passes MIN_SCORE and
    MIN_PEAK. Works on the mask's bounding box (full-size parts come back)."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) < 2 * MIN_PART_PX and len(cols) < 2 * MIN_PART_PX:
        return [mask], -1, -1.0
    box = (slice(rows[0], rows[-1] + 1), slice(cols[0], cols[-1] + 1))
    crop = np.ascontiguousarray(lab[box])
    if _spread(_pixels(crop).take(np.flatnonzero(mask[box]), axis=0)) < (0.8 * MIN_SPREAD) ** 2:
        return [mask], -1, -1.0               # a plain face: no profile can have the spread
    subs, axis, score = _cut(mask[box], crop, depth)
    if len(subs) == 1:
        return [mask], -1, score
    parts = []
    for sub in subs:
        full = np.zeros_like(mask)
        full[box] = sub
        parts.append(full)
    return parts, axis, score


def _spread(px: np.ndarray) -> float:
    """The summed CIELAB variance of N x 3 pixels, lightness at `L_WEIGHT` (how much print a mask
    holds), a channel at a time on contiguous columns (an N x 3 column reduction is several times
    slower)."""
    return float(sum(np.var(np.ascontiguousarray(px[:, k], dtype=np.float64) * w)
                     for k, w in enumerate((L_WEIGHT, 1.0, 1.0))))


def _cut(mask: np.ndarray, lab: np.ndarray, depth: int) -> tuple[list[np.ndarray], int, float]:
    """`repeat_parts` on a cropped mask and image."""
    found: tuple[float, int, float, int] = (-1.0, -1, 0.0, 0)
    for axis in (0, 1):
        lo, prof = profile(mask, lab, axis)
        s, shifted, cut = best_cut(prof)
        if s >= MIN_SCORE and s - shifted >= MIN_PEAK and s > found[0]:
            found = (s, axis, cut, lo)
    s, axis, cut, lo = found
    if axis < 0:
        return [mask], -1, s
    grid = np.arange(mask.shape[axis])
    sel = grid < lo + round(cut)
    first = mask & (sel[:, None] if axis == 0 else sel[None, :])
    parts = []
    for part in (first, mask & ~first):
        more, ax, _ = _cut(part, lab, depth - 1) if depth > 1 else ([part], -1, 0.0)
        parts.extend(more if ax == axis else [part])
    return parts, axis, s
