"""Cutting an L-shaped mask (the strip of one box merged with the end of another) along a
straight line into two rectangles, kept only when a part joins a neighbour into a type face."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shelfpick.perception.masks import border_sides
from shelfpick.perception.repairs.crop import box_nonzero
from shelfpick.perception.repairs.measure import Measured, RepairContext
from shelfpick.perception.repairs.planes import join_on_plane, plane_dist, rect_fill


@dataclass(frozen=True, eq=False)
class _LJoin:
    """An L's part (`piece`) joined with neighbour `j` into the type face `face`; `rest` the other part."""

    piece: np.ndarray
    rest: np.ndarray
    j: int
    face: Measured


def cut_l_shapes(masks: list[np.ndarray], ctx: RepairContext, max_fill: float = 0.8, part_fill: float = 0.8,
                 angles: tuple[float, ...] = ()) -> tuple[list[np.ndarray], list[str]]:
    """Cut an L-shaped mask (no type face, filling its rectangle < `max_fill`: the strip of one
    box merged with the end of another) along a straight line that leaves two rectangles,
    and keep the cut only when a part joins a neighbouring mask into a type face (within `tol`,
    filling its rectangle >= `join_fill`; never a union that merely fits inside one).

    The line runs along an image row or column where both parts fill their rectangles
    >= `part_fill`; where no such cut joins, at the L's corner (where the mask's extent across
    the line jumps most, one part filling >= `part_fill`): a strip whose edge to the rest of
    its face is ragged (a label or tape split between them) fills no rectangle. `angles` (deg,
    off by default) also tries lines turned by each angle (the mask filling its turned
    rectangle < `max_fill`): on a test a turned cut joined a union holding 11% of another
    box, and the framed shelf it was meant for (perceive_plan seed 11) needs no turned line."""
    out = list(masks)
    notes: list[str] = []
    i = 0
    while i < len(out):
        m = out[i]
        f = ctx.measure(m)
        if f is None or f.err <= ctx.cat.tol or border_sides(m) or rect_fill(m) >= max_fill:
            i += 1
            continue
        others = [o for j, o in enumerate(out) if j != i]
        found = _l_cut(m, others, ctx, max_fill, part_fill, angles)
        if found is None:
            i += 1
            continue
        deg, joined = found
        notes.append(f"cut an L-shaped {f.face.size_cm} mask in two"
                     f"{'' if deg == 0.0 else f' (line turned {deg:+.0f} deg)'}; "
                     f"a part joined its neighbour into a {joined.face.face.size_cm} type face")
        others[joined.j] = joined.face.mask
        out = others[:i] + [joined.rest] + others[i:]
        i = 0
    return out, notes


def _l_cut(m: np.ndarray, others: list[np.ndarray], ctx: RepairContext, max_fill: float, part_fill: float,
           angles: tuple[float, ...]) -> tuple[float, _LJoin] | None:
    """(the line's angle, the join) of the first line (best fill, then the L's corner, at 0 deg
    then at `angles`) whose part joins a neighbour; None if none does."""
    ys, xs = box_nonzero(m)
    for deg, step in ((0.0, False),) + tuple((a, True) for a in (0.0,) + tuple(angles)):
        if deg != 0.0 and _fill_at(ys, xs, deg) >= max_fill:
            continue          # a rectangle at this angle: not an L
        cuts = []
        for _, _, near_side in _best_l_cut(ys, xs, deg, ctx.cat.l_margin_px, part_fill, step):
            a = np.zeros_like(m)
            a[ys[near_side], xs[near_side]] = True
            cuts += [(a, m & ~a), (m & ~a, a)]
        joined = _l_join(cuts, others, ctx)
        if joined is not None:
            return deg, joined
    return None


def _l_join(cuts: list[tuple[np.ndarray, np.ndarray]], others: list[np.ndarray],
            ctx: RepairContext) -> _LJoin | None:
    """The best (piece, rest, neighbour index, joined face) among the cuts: the piece joins
    a neighbour on its plane into a type face filling its rectangle; None if none does."""
    cat = ctx.cat
    joined = None
    for piece, rest in cuts:
        near = ctx.near(piece)
        for j, o in enumerate(others):
            if not near.touches(o):
                continue
            fo = ctx.measure(o)
            if fo is None or plane_dist(fo.face, piece, ctx) > cat.plane_tol:
                continue
            taken = rest.copy()
            for q in others:
                if q is not o:
                    taken |= q
            union, fill = join_on_plane(piece, o, fo.face, taken, ctx)
            if fill < cat.join_fill:
                continue
            fu = ctx.measure_once(union)
            if fu is not None and fu.err <= cat.tol and (joined is None or fu.err < joined.face.err):
                joined = _LJoin(piece, rest, j, fu)
    return joined


def _rotated(ys: np.ndarray, xs: np.ndarray, deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates in image axes turned by `deg` (0: columns, rows)."""
    if deg == 0.0:
        return xs.astype(np.float64), ys.astype(np.float64)
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return xs * c + ys * s, ys * c - xs * s


def _fill_at(ys: np.ndarray, xs: np.ndarray, deg: float) -> float:
    """Pixel count over the area of the rectangle turned by `deg` around the pixels."""
    u, v = _rotated(ys, xs, deg)
    if not len(u):
        return 0.0
    return float(len(u)) / float((np.ptp(u) + 1) * (np.ptp(v) + 1))


class _Sweep:
    """A line swept along `t` through pixels at (t, o): per bin position, the pixel count and
    rectangle of the part before it (a) and from it on (b)."""

    def __init__(self, t: np.ndarray, o: np.ndarray) -> None:
        self.t = t
        self.bi = bi = np.floor(t - t.min() + 1e-9).astype(int)
        self.nb = nb = int(bi.max()) + 1
        self.cnt = cnt = np.bincount(bi, minlength=nb).astype(float)
        self.omin, self.omax = omin, omax = np.full(nb, np.inf), np.full(nb, -np.inf)
        np.minimum.at(omin, bi, o)
        np.maximum.at(omax, bi, o)
        tmin, tmax = np.full(nb, np.inf), np.full(nb, -np.inf)
        np.minimum.at(tmin, bi, t)
        np.maximum.at(tmax, bi, t)
        # part a: bins < pos; part b: bins >= pos
        self.ca, self.cb = np.cumsum(cnt), np.cumsum(cnt[::-1])[::-1]
        self.amin, self.amax = np.minimum.accumulate(omin), np.maximum.accumulate(omax)
        self.bmin, self.bmax = np.minimum.accumulate(omin[::-1])[::-1], np.maximum.accumulate(omax[::-1])[::-1]
        self.atmax = np.maximum.accumulate(tmax)
        self.btmin = np.minimum.accumulate(tmin[::-1])[::-1]

    def empty_side(self, pos: int) -> bool:
        return self.ca[pos - 1] == 0 or self.cb[pos] == 0

    def fills(self, pos: int) -> tuple[float, float]:
        """How well part a and part b fill their rectangles with the line at bin `pos`."""
        t, ca, cb, amin, amax, bmin, bmax = self.t, self.ca, self.cb, self.amin, self.amax, self.bmin, self.bmax
        fa = ca[pos - 1] / ((self.atmax[pos - 1] - t.min() + 1) * (amax[pos - 1] - amin[pos - 1] + 1))
        fb = cb[pos] / ((t.max() - self.btmin[pos] + 1) * (bmax[pos] - bmin[pos] + 1))
        return fa, fb

    def all_fills(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions 1..nb-1, `fills` of part a and of part b at each), for every line at once."""
        pos = np.arange(1, self.nb)
        t, ca, cb = self.t, self.ca, self.cb
        fa = ca[pos - 1] / ((self.atmax[pos - 1] - t.min() + 1) * (self.amax[pos - 1] - self.amin[pos - 1] + 1))
        fb = cb[pos] / ((t.max() - self.btmin[pos] + 1) * (self.bmax[pos] - self.bmin[pos] + 1))
        return pos, fa, fb

    def best_fill(self, margin: int, part_fill: float) -> tuple[float, int] | None:
        """(score, pos) of the line (at least `margin` bins in from either end) whose two parts
        both fill their rectangles best (>= `part_fill`); the first such line on a tie."""
        pos, fa, fb = self.all_fills()
        score = np.minimum(fa, fb)
        ok = (pos >= margin) & (pos <= self.nb - margin) & (self.ca[pos - 1] != 0) & (self.cb[pos] != 0) \
            & (score >= part_fill)
        if not ok.any():
            return None
        k = int(np.argmax(np.where(ok, score, -np.inf)))
        return float(score[k]), int(pos[k])

    def corner(self, margin: int, part_fill: float) -> int | None:
        """The L's corner: where the mask's extent across the line jumps most, one part filling
        >= `part_fill` (a part may be ragged, a label edge or tape along it); the first on a tie."""
        span = np.where(self.cnt > 0, self.omax - self.omin + 1, 0.0)
        pos, fa, fb = self.all_fills()
        if margin < 1:
            return None           # no window to compare either side of a line
        m = margin
        ok = (pos >= m) & (pos <= self.nb - m) & (self.ca[pos - 1] != 0) & (self.cb[pos] != 0) \
            & (np.maximum(fa, fb) >= part_fill)
        if not ok.any():
            return None
        d = np.full(len(pos), -np.inf)
        for k in np.flatnonzero(ok):
            p = int(pos[k])
            d[k] = abs(_median(span[max(0, p - margin):p]) - _median(span[p:p + margin]))
        return int(pos[int(np.argmax(d))])


def _median(v: np.ndarray) -> float:
    """`float(np.median(v))` of a short 1-D array without NaN: its middle value after a sort, or
    the two middle ones' mean as numpy takes it ((a + b) / 2), without np.median's set-up (~20 us)."""
    s = np.sort(v)
    h = len(s) // 2
    return float(s[h]) if len(s) % 2 else float((s[h - 1] + s[h]) / 2)


def _best_l_cut(ys: np.ndarray, xs: np.ndarray, deg: float, margin: int,
                part_fill: float, step: bool = False) -> list[tuple[float, int, np.ndarray]]:
    """Per axis of the frame turned by `deg`: the straight cut (at least `margin` px in from
    either end) whose two parts both fill their turned rectangles best (>= `part_fill`), as
    (score, axis, pixels on the near side); at 0 deg this is a cut along an image row/column.
    `step`: also the cut where the extent across it jumps most, one part filling >= `part_fill`."""
    u, v = _rotated(ys, xs, deg)
    out = []
    for axis, (t, o) in enumerate(((v, u), (u, v))):
        sw = _Sweep(t, o)
        best = sw.best_fill(margin, part_fill)
        if best is not None:
            out.append((best[0], axis, sw.bi < best[1]))
        if step:
            pos = sw.corner(margin, part_fill)
            if pos is not None and (best is None or pos != best[1]):
                out.append((0.0, axis, sw.bi < pos))
    return out
