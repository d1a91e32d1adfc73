"""Where a seam runs across a face: colour lines and steps, and depth steps, per 3 mm band."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from shelfpick.perception.faces import FrontFace, face_axes
from shelfpick.perception.geometry import backproject
from shelfpick.perception.pixels import count

if TYPE_CHECKING:
    from shelfpick.perception.catalogue import Catalogue
    from shelfpick.perception.repairs.measure import RepairContext

_LINE_R, _STEP_W = 3, 5       # bins: a line against the bands this far either side; a step over this many


@dataclass(frozen=True, eq=False)
class Evidence:
    bins: np.ndarray        # bin centres (m)
    score: np.ndarray       # seam score per bin: 1 = the weakest seam taken
    depth: np.ndarray | None = None   # the depth step's share of it (a step >= depth_step is 1)


def line_evidence(t: np.ndarray, o: np.ndarray, ys: np.ndarray, xs: np.ndarray, lab: np.ndarray | None,
                  face: FrontFace, ctx: "RepairContext", bin_m: float = 0.003) -> Evidence:
    """How much a seam runs across the face at each position along `t` (`o`: across it).

    Colour: the mean colour of each 3 mm band across the face (texture and grain
    average out along the band, a seam line does not): a band that differs from
    the bands 9 mm either side, or a colour step across it, in units of the
    profile's own robust noise. Depth: the step of the mean plane residual
    across the position.
    """
    lo, hi = float(t.min()), float(t.max())
    nb = max(1, int(math.ceil((hi - lo) / bin_m)))
    bi = np.clip(((t - lo) / bin_m).astype(int), 0, nb - 1)
    olo, ohi = np.quantile(o, (0.08, 0.92))
    inner = (o > olo) & (o < ohi)
    score = np.zeros(nb)
    if lab is not None:
        score = _colour_score(bi[inner], lab[ys[inner], xs[inner]].astype(np.float64), nb, ctx.cat, score)
    dscore = _depth_score(bi, ys, xs, inner, face, ctx, nb, score)
    return Evidence(lo + (np.arange(nb) + 0.5) * bin_m, score, dscore)


def _colour_score(bi: np.ndarray, col: np.ndarray, nb: int, cat: "Catalogue", score: np.ndarray) -> np.ndarray:
    """`score` raised by the colour lines and steps of the bands' mean colour profile."""
    r, w = _LINE_R, _STEP_W
    cnt = np.bincount(bi, minlength=nb).astype(float)
    good = cnt >= 5
    if count(good) <= 4 * w:
        return score
    for c in range(3):
        prof = np.bincount(bi, weights=col[:, c], minlength=nb) / np.maximum(cnt, 1)
        idx = np.arange(nb)
        prof = np.interp(idx, idx[good], prof[good])
        line = np.zeros(nb)
        line[r:-r] = prof[r:-r] - 0.5 * (prof[:-2 * r] + prof[2 * r:])
        cs = np.concatenate([[0], np.cumsum(prof)])
        stp = np.zeros(nb)
        k = np.arange(w, nb - w)
        stp[k] = (cs[k] - cs[k - w]) / w - (cs[k + w + 1] - cs[k + 1]) / w
        for v in (line, stp):
            core = v[w:-w] if nb > 2 * w else v
            noise = 1.4826 * float(np.median(np.abs(core - np.median(core)))) + 0.3
            score = np.maximum(score, np.abs(v) / (noise * cat.min_evidence))
    return score


def _depth_score(bi: np.ndarray, ys: np.ndarray, xs: np.ndarray, inner: np.ndarray, face: FrontFace,
                 ctx: "RepairContext", nb: int, score: np.ndarray) -> np.ndarray:
    """Per bin the step of the mean plane residual across it, in units of `depth_step`;
    `score` is raised to it in place."""
    w = _STEP_W
    d = ctx.depth[ys, xs].astype(np.float64)
    ok = np.isfinite(d) & (d > 0) & inner
    dscore = np.zeros(nb)
    if count(ok) <= 50:
        return dscore
    p = backproject(ctx.camera, xs[ok].astype(np.float64), ys[ok].astype(np.float64), d[ok])
    res = (p - np.asarray(face.center)) @ face_axes(face)[:, 1]
    s_ = np.bincount(bi[ok], weights=res, minlength=nb)
    c_ = np.bincount(bi[ok], minlength=nb).astype(float)
    cs, cc = np.concatenate([[0], np.cumsum(s_)]), np.concatenate([[0], np.cumsum(c_)])
    for k in range(w, nb - w):
        n1, n2 = cc[k] - cc[k - w], cc[k + w + 1] - cc[k + 1]
        if n1 > 10 and n2 > 10:
            stp = abs((cs[k] - cs[k - w]) / n1 - (cs[k + w + 1] - cs[k + 1]) / n2)
            dscore[k] = stp / ctx.cat.depth_step
            score[k] = max(score[k], dscore[k])
    return dscore


def peak_near(ev: Evidence, pos: float, win: float) -> list[tuple[float, float, bool]]:
    """The best seam position within `win` of `pos`, its score (>= 1 means a seam) and whether
    a depth step (>= depth_step) runs there (an empty list when no bin is that close)."""
    sel = np.flatnonzero(np.abs(ev.bins - pos) <= win)
    if len(sel) == 0:
        return []
    score = ev.score[sel]
    k = int(np.argmax(score))
    step = ev.depth is not None and bool(ev.depth[sel[k]] >= 1.0)
    return [(float(ev.bins[sel[k]]), float(score[k]), step)]
