"""Masks that span a depth step between two fronts: a type-face mask that is two boxes' halves
(split at the step), and a face's part that merged with the box beneath it (given back)."""
from __future__ import annotations

from functools import partial

import cv2
import numpy as np

from shelfpick.perception.masks import border_sides
from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.crop import Window, box
from shelfpick.perception.repairs.measure import Measured, RepairContext, neighbour_pieces
from shelfpick.perception.repairs.parts import Handover, give_parts, one_part, part_to_pieces
from shelfpick.perception.repairs.planes import coords, join_on_plane, on_plane, plane_dist, plane_res
from shelfpick.perception.repairs.seams import line_evidence


def split_stepped_faces(masks: list[np.ndarray], ctx: RepairContext,
                        min_part: float = 0.05) -> tuple[list[np.ndarray], list[str]]:
    """Split a mask that measures as a type face but is two boxes: the left halves of two
    stacked faces, each cut down one line by the segmenter, merged into one mask that happens
    to have a type face's size (17x50 cm from two 23x25 faces).

    `split_faces` never looks at such a mask (it is a type face), so this runs once the pieces
    are as joined as they get. The mask splits only at a depth step (>= `depth_step`, two
    fronts; a label edge is flat) running across it, each part at least `min_part` long, and
    only when BOTH parts join a different neighbouring piece (no type face itself) on the
    part's own plane into a type face filling its rectangle >= `join_fill`; the three masks
    become the two joined faces."""
    out = [np.asarray(m, bool) for m in masks]
    notes: list[str] = []
    if len(out) < 3:
        return out, notes
    i = 0
    while i < len(out):
        m = out[i]
        f = ctx.measure(m)
        if f is None or f.err > ctx.cat.tol or border_sides(m):
            i += 1
            continue
        pieces = neighbour_pieces(i, out, ctx)
        done = _stepped_split(m, i, f, pieces, out, ctx, min_part) if len(pieces) >= 2 else None
        if done is None:
            i += 1
            continue
        (ja, ua), (jb, ub), axis, step = done
        fa, fb = ctx.measure(ua), ctx.measure(ub)
        notes.append(f"split a {f.face.size_cm} type-face mask "
                     f"{'across' if axis == 1 else 'down'} a {step * 100:.1f} cm depth step; its parts "
                     f"joined their neighbouring pieces into {fa.face.size_cm} and {fb.face.size_cm} faces")
        out = [o for j, o in enumerate(out) if j not in (i, ja, jb)] + [ua, ub]
        i = 0
    return out, notes


def _stepped_split(m: np.ndarray, i: int, f: Measured, pieces: list[int], out: list[np.ndarray],
                   ctx: RepairContext, min_part: float):
    """((piece a, union a), (piece b, union b), axis, step in m) for the best depth-step line
    through mask `m` whose two parts each join one of `pieces` into a type face; else None."""
    ys, xs, cx, cz = coords(f.face, m, ctx.camera)
    best = None
    for axis in (1, 0):
        t, o = (cz, cx) if axis == 1 else (cx, cz)
        lo, hi = np.quantile(t, (0.01, 0.99))
        if hi - lo < 2 * min_part:
            continue
        ev = line_evidence(t, o, ys, xs, None, f.face, ctx)
        sel = np.flatnonzero((ev.bins >= lo + min_part) & (ev.bins <= hi - min_part) & (ev.depth >= 1.0))
        if not len(sel):
            continue
        pk = int(sel[np.argmax(ev.depth[sel])])
        a = t < ev.bins[pk]
        parts = []
        for sel_ in (a, ~a):
            p = np.zeros_like(m)
            p[ys[sel_], xs[sel_]] = True
            parts.append(p)
        joins = []
        for p, rest in ((parts[0], parts[1]), (parts[1], parts[0])):
            cand = _step_join(p, rest, i, pieces, out, ctx)
            if cand is None:
                break
            joins.append(cand)
        if len(joins) < 2 or joins[0][0] == joins[1][0]:
            continue
        step = float(ev.depth[pk]) * ctx.cat.depth_step
        if best is None or step > best[3]:
            best = ((joins[0][0], joins[0][1]), (joins[1][0], joins[1][1]), axis, step)
    return best


def _step_join(p: np.ndarray, rest: np.ndarray, i: int, pieces: list[int], out: list[np.ndarray],
               ctx: RepairContext) -> tuple[int, np.ndarray, float] | None:
    """(piece index, union, error) of the best piece that part `p` of mask i joins on p's
    plane into a type face filling its rectangle; None if none does."""
    cat = ctx.cat
    fp = ctx.measure_once(p)
    if fp is None:
        return None
    nearp = ctx.near(p)
    cand = None
    for j in pieces:
        if not nearp.touches(out[j]) or plane_dist(fp.face, out[j], ctx) > cat.plane_tol:
            continue
        taken = rest.copy()
        for q, oq in enumerate(out):
            if q not in (i, j):
                taken |= oq
        union, fill = join_on_plane(p, out[j], fp.face, taken, ctx)
        if fill < cat.join_fill:
            continue
        fu = ctx.measure_once(union)
        if fu is not None and fu.err <= cat.tol and (cand is None or fu.err < cand[2]):
            cand = (j, union, fu.err)
    return cand


def take_stepped_parts(masks: list[np.ndarray], ctx: RepairContext,
                       plane_tol: float = 0.006) -> tuple[list[np.ndarray], list[str]]:
    """Give pieces of a face back the part of another mask that lies on their plane, a depth
    step away from the rest of that mask: a face cut by a tape band whose part below the band
    merged with the box beneath it (same colour, a front 1-3 cm nearer or further: under the
    depth-gap split of `masks.refine`); `take_bridging_parts` misses it because that part lies
    outside the pieces' rectangle.

    For a mask that is no type face (not cut by the image border) with neighbouring pieces (no
    type faces) on one plane (the group grown through the pieces' own neighbours): its pixels
    within `plane_tol` of that plane and nearer to it than to the plane of the mask's other
    pixels (where a yawed face's plane crosses it, a pixel goes with its nearest clear
    neighbour), connected to the pieces, go to them; only when what is left of the mask lies off
    that plane (median distance > `cat.plane_tol`) and is a type face filling its rectangle >=
    `join_fill`, and the pieces with that part join into a type face filling its rectangle >=
    `join_fill`."""
    return give_parts(masks, ctx, 2, partial(_stepped_attempt, plane_tol=plane_tol))


def _stepped_attempt(i: int, m: np.ndarray, f: Measured, out: list[np.ndarray], ctx: RepairContext,
                     plane_tol: float) -> Handover | None:
    pieces = neighbour_pieces(i, out, ctx)
    done = _stepped_part(m, i, pieces, out, ctx, plane_tol) if pieces else None
    if done is None:
        return None
    rest, union, grp, fr, fu, step = done
    return Handover(tuple(grp), rest, union,
                    f"gave the part of a {f.face.size_cm} mask {step * 100:.1f} cm off its rest "
                    f"to {len(grp)} neighbouring piece(s): {fu.face.size_cm} and {fr.face.size_cm}")


def _stepped_part(m: np.ndarray, i: int, pieces: list[int], out: list[np.ndarray], ctx: RepairContext,
                  plane_tol: float):
    """(rest of m, joined face mask, piece indices, their faces, depth step) or None; see
    `take_stepped_parts`."""
    fa = max((ctx.measure(out[j]) for j in pieces), key=lambda q: count(q.mask))
    grp, gm = _face_group(m, i, fa, pieces, out, ctx)
    on = _on_pieces_plane(m, fa, ctx, plane_tol)
    if on is None:
        return None
    near = ctx.near(gm)
    n, lbl = cv2.connectedComponents(on.astype(np.uint8), connectivity=4)
    touch = np.unique(lbl[near.full() & on])
    part = np.isin(lbl, touch[touch > 0])
    part = m & (cv2.morphologyEx(part.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0)
    rest = m & ~part
    if count(part) < 0.05 * count(m) or count(rest) < 0.3 * count(m):
        return None
    kept = one_part(rest)
    if kept is None:
        return None
    rest, specks = kept
    if specks.any():     # specks next to the part are its holes; others (on the rest's rim) are dropped
        n2, lbl2 = cv2.connectedComponents(specks.astype(np.uint8), connectivity=8)
        grow = cv2.dilate(part.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        touch = np.unique(lbl2[grow & specks])
        part = part | np.isin(lbl2, touch[touch > 0])
    step = plane_dist(fa.face, rest, ctx)
    if step <= ctx.cat.plane_tol:
        return None          # no depth step: a label or tape edge, not two fronts
    done = part_to_pieces(rest, part, gm, fa.face, i, grp, out, ctx)
    if done is None:
        return None
    fr, union, fu = done
    return rest, union, grp, fr, fu, step


def _face_group(m: np.ndarray, i: int, fa: Measured, pieces: list[int], out: list[np.ndarray],
                ctx: RepairContext) -> tuple[list[int], np.ndarray]:
    """The pieces on the plane of the largest one, grown through their own neighbours on that
    plane (the other pieces of that face): (indices, their union)."""
    cat = ctx.cat
    grp = [j for j in pieces if plane_dist(fa.face, out[j], ctx) <= cat.plane_tol]
    gm = np.zeros_like(m)
    for j in grp:
        gm |= out[j]
    grown = True
    while grown:
        grown = False
        near = ctx.near(gm)
        for q, oq in enumerate(out):
            if q == i or q in grp or not near.touches(oq) or border_sides(oq):
                continue
            fq = ctx.measure(oq)
            if fq is None or fq.err <= cat.tol or plane_dist(fa.face, oq, ctx) > cat.plane_tol:
                continue
            grp.append(q)
            gm |= oq
            grown = True
    return grp, gm


def _on_pieces_plane(m: np.ndarray, fa: Measured, ctx: RepairContext, plane_tol: float) -> np.ndarray | None:
    """The pixels of m nearer to the pieces' plane (within `plane_tol`) than to the plane of
    m's part off it; where the two planes cross (a yawed face) neither is nearer, and such a
    pixel goes with the nearest pixel that is clearly on one of them. None if m has no part
    off the plane to measure."""
    on = on_plane(fa.face, m, ctx, plane_tol)
    fr0 = ctx.measure_once(m & ~on)
    if fr0 is None:
        return None
    # on m's box (2 px round it), where the opening is the full frame's and outside which
    # nothing is on; the distances on the full frame (on a crop they may differ in the last bit)
    win = box(m, 2)
    mw = m[win]
    dp, dr = plane_res(fa.face, m, ctx, win), plane_res(fr0.face, m, ctx, win)
    on = mw & (dp <= plane_tol) & (dp + 0.003 < dr)
    off = mw & (dr + 0.003 < dp)
    amb = mw & ~on & ~off
    if amb.any() and on.any() and off.any():
        d_on, d_off = (cv2.distanceTransform(_framed_off(~p, m.shape, win), cv2.DIST_L2, 3)[win]
                       for p in (on, off))
        on = on | (amb & (d_on < d_off))
    out = np.zeros_like(m)
    out[win] = cv2.morphologyEx(on.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    return out


def _framed_off(off_set: np.ndarray, shape: tuple[int, ...], win: Window) -> np.ndarray:
    """The full frame's 0/1 image (uint8) of the pixels off a set of pixels held in the crop
    `win`, given that crop's `off_set` (everywhere outside the crop is off the set)."""
    out = np.ones(shape, np.uint8)
    out[win] = off_set
    return out
