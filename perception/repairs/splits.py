"""Splitting a mask that is two or more flush faces (stacked or side by side, of one colour)
at the line where it falls into type faces, when a seam runs along that line."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.measure import Measured, RepairContext
from shelfpick.perception.repairs.planes import coords, extent, join_on_plane, plane_dist
from shelfpick.perception.repairs.seams import line_evidence, peak_near


@dataclass(frozen=True, eq=False)
class _Cut:
    """A candidate cut along `axis` (1: across z, stacked; 0: across x) at `pos`: side a is
    `a` (pixels with t < pos), the sides' sizes and errors, whether one side is a piece of a
    face ("row"/"pieces", else False) and whether the other is a staircase of faces."""

    key: tuple
    axis: int
    pos: float
    a: np.ndarray
    wa: float
    ha: float
    wb: float
    hb: float
    ea: float
    eb: float
    piece: str | bool
    stagger: bool


def split_faces(masks: list[np.ndarray], ctx: RepairContext, max_parts: int = 4,
                only: list[np.ndarray] | None = None) -> tuple[list[np.ndarray], list[str]]:
    """Split a mask that is no type face at the line where it falls into two type faces,
    when a seam (colour edge line or depth step) runs along that line; `only`: the masks to
    look at (the rest are kept as they are)."""
    out: list[np.ndarray] = []
    notes: list[str] = []
    for m in masks:
        if only is not None and not any(m is q for q in only):
            out.append(m)
            continue
        parts, said = split_one(np.asarray(m, bool), ctx, max_parts, others=masks)
        out.extend(parts)
        notes.extend(said)
    return out, notes


def split_one(mask: np.ndarray, ctx: RepairContext, budget: int, row_axis: int | None = None,
              others: list[np.ndarray] | None = None) -> tuple[list[np.ndarray], list[str]]:
    """One mask cut into up to `budget` type faces, and what was done. `row_axis`: the mask
    is the rest of a row of faces cut off a longer mask along this axis; it may then also
    split into a type face and a piece of one (its other part was cut off the same face by
    the segmenter, and `join_pieces` joins them again)."""
    cat = ctx.cat
    if budget <= 1:
        return [mask], []
    f = ctx.measure(mask)
    if f is None or f.err <= cat.tol:
        return [mask], []
    face = f.face
    side_min = min(cat.sides) - cat.tol
    if max(face.width, face.height) < 2 * side_min:
        return [mask], []
    ys, xs, cx, cz = coords(face, mask, ctx.camera)
    cands = [c for axis in (1, 0)              # stacked (split along z) first, then side by side
             for c in _axis_cuts(axis, f, ys, xs, cx, cz, ctx, budget, row_axis)]
    chosen = _choose(cands, mask, ys, xs, ctx, budget, others)
    if chosen is None:
        return [mask], []
    best, pa, pb, staircase = chosen
    how = "across" if best.axis == 1 else "down"
    if staircase is not None:
        first, parts, sub = staircase
        return [first] + parts, [f"split a {face.size_cm} staircase of faces {how} "
                                 f"its seams into {len(parts) + 1} type faces"] + sub
    note = (f"split a {face.size_cm} face {how} its seam into {best.wa * 100:.0f}x{best.ha * 100:.0f} and "
            f"{best.wb * 100:.0f}x{best.hb * 100:.0f} cm (evidence {best.key[3]:.2f}"
            f"{', depth step' if best.key[2] else ''})")
    left, lnotes = split_one(pa, ctx, budget - 1, best.axis if best.ea > cat.tol else None, others)
    right, rnotes = split_one(pb, ctx, budget - 1, best.axis if best.eb > cat.tol else None, others)
    return left + right, [note] + lnotes + rnotes


def _axis_cuts(axis: int, f: Measured, ys: np.ndarray, xs: np.ndarray, cx: np.ndarray, cz: np.ndarray,
               ctx: RepairContext, budget: int, row_axis: int | None) -> list[_Cut]:
    """The cuts along one axis: at each distance of a type side from either end, the best seam
    within 1.5 cm (seam evidence per 3 mm bin), judged by `_judge`."""
    cat = ctx.cat
    side_min = min(cat.sides) - cat.tol
    t = cz if axis == 1 else cx
    o = cx if axis == 1 else cz
    lo, hi = np.quantile(t, (0.01, 0.99))
    length = hi - lo
    if length < 2 * side_min:
        return []
    cands = set()
    for s in cat.sides:
        for pos in (lo + s, hi - s):
            if lo + side_min <= pos <= hi - side_min:
                cands.add(round(float(pos), 3))
    if not cands:
        return []
    ev = line_evidence(t, o, ys, xs, ctx.lab, f.face, ctx)
    out = []
    for pos in sorted(cands):
        for p2, score, step in peak_near(ev, pos, 0.015):
            c = _judge(axis, p2, score, step, t, cx, cz, f, ctx, budget, row_axis)
            if c is not None:
                out.append(c)
    return out


def _judge(axis: int, p2: float, score: float, step: bool, t: np.ndarray, cx: np.ndarray, cz: np.ndarray,
           f: Measured, ctx: RepairContext, budget: int, row_axis: int | None) -> _Cut | None:
    """The cut at `p2` if its seam is strong enough for what it leaves: two type faces; a type
    face and a piece of one (row_axis); or a type face and a row of type faces (a stack of
    three flush boxes is cut one seam at a time), straight or a staircase."""
    cat = ctx.cat
    a = t < p2
    if count(a) < 50 or count(~a) < 50:
        return None
    wa, ha = (extent(cx[a]), extent(cz[a]))
    wb, hb = (extent(cx[~a]), extent(cz[~a]))
    if axis == 1:
        ha, hb = p2 - np.quantile(t[a], 0.01), np.quantile(t[~a], 0.99) - p2
    else:
        wa, wb = p2 - np.quantile(t[a], 0.01), np.quantile(t[~a], 0.99) - p2
    ea, eb = cat.error(wa, ha), cat.error(wb, hb)
    # two flush faces of one colour leave only a faint seam: a mask far off every type
    # face that falls into exactly two type faces there is cut on weaker evidence
    need = cat.weak_evidence if f.err > cat.row_margin and max(ea, eb) <= cat.tol else 1.0
    if score < need or min(ea, eb) > cat.tol:
        return None
    rest = (wb, hb) if ea <= cat.tol else (wa, ha)
    # (the weakest case: its type face must match to half the tolerance)
    # (or, for any mask, when the piece joins a neighbour that is itself a piece:
    # the segmenter cut a face and gave one part to the box beside it)
    piece = ((row_axis in (axis, None)) and max(ea, eb) > cat.tol and cat.fits(*rest)
             and min(rest) >= 0.05 and min(ea, eb) <= cat.tol / 2)
    piece = piece and ("row" if row_axis == axis else "pieces")
    stagger = False
    if max(ea, eb) > cat.tol and not piece:
        # one part a type face, the other (budget left) itself two faces in a row along the
        # same axis (only for a mask far off any type face: a face measured a few cm too
        # long, labels on it, is not a stack of smaller faces)
        if f.err <= cat.row_margin or min(ea, eb) > cat.tol:
            return None
        if not any(cat.composable(rest[0], rest[1], axis, k) for k in range(2, budget)):
            # a staircase: faces of one colour stacked with offsets (a real seam
            # needed, and kept only if the rest cuts into type faces down to the last)
            if score < 1.0 or not any(cat.composable(rest[0], rest[1], axis, k, staggered=True)
                                      for k in range(2, budget)):
                return None
            stagger = True
    # a depth step is two fronts (a label or tape edge is flat): it beats colour alone;
    # a faint seam (under 1, `weak_evidence`) only where no real seam gives a cut
    key = (score >= 1.0, max(ea, eb) <= cat.tol, step, score, -max(ea, eb))
    return _Cut(key, axis, p2, a, wa, ha, wb, hb, ea, eb, piece, stagger)


def _choose(cands: list[_Cut], mask: np.ndarray, ys: np.ndarray, xs: np.ndarray, ctx: RepairContext,
            budget: int, others: list[np.ndarray] | None):
    """(the cut taken, its two parts, (first face, the staircase's other faces, their notes) or
    None) for the best cut that stands, staircases first; None if none does. A piece must join
    a neighbour into a type face (else the cut is at a label or tape); a staircase's rest must
    cut into type faces down to the last."""
    tol = ctx.cat.tol
    for c in sorted(cands, key=lambda c: (not c.stagger,) + c.key, reverse=True):
        pa = np.zeros_like(mask)
        pb = np.zeros_like(mask)
        pa[ys[c.a], xs[c.a]] = True
        pb[ys[~c.a], xs[~c.a]] = True
        if c.piece and not _piece_joins(pa if c.ea > tol else pb, pb if c.ea > tol else pa, others or [],
                                        ctx, pieces_only=c.piece == "pieces"):
            continue
        staircase = None
        if c.stagger:
            parts, sub = split_one(pb if c.ea <= tol else pa, ctx, budget - 1, None, others)
            errs = [ctx.measure(q) for q in parts]
            if len(parts) < 2 or any(e is None or e.err > tol for e in errs):
                continue
            staircase = (pa if c.ea <= tol else pb, parts, sub)
        return c, pa, pb, staircase
    return None


def _piece_joins(piece: np.ndarray, rest: np.ndarray, others: list[np.ndarray], ctx: RepairContext,
                 pieces_only: bool = False) -> bool:
    """Whether a piece, joined with a neighbouring mask on its plane (not taking pixels of
    `rest` or of other masks), makes a type face that fills its rectangle (`pieces_only`: a
    neighbour that is itself no type face)."""
    cat = ctx.cat
    near = ctx.near(piece)
    for m in others:
        if (m & piece).any() or not near.touches(m):
            continue
        fm = ctx.measure(m)
        if fm is None or (pieces_only and fm.err <= cat.tol) or plane_dist(fm.face, piece, ctx) > cat.plane_tol:
            continue
        taken = rest.copy()
        for q in others:
            if q is not m:
                taken |= q & ~piece
        union, fill = join_on_plane(piece, m, fm.face, taken, ctx)
        if fill < cat.join_fill:
            continue
        fu = ctx.measure_once(union)
        if fu is not None and fu.err <= cat.tol:
            return True
    return False
