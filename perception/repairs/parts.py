"""Giving part of a mask that is no type face to neighbouring pieces of another face: the
loop the band and depth-step passes share, and the check that both results are type faces."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from shelfpick.perception.faces import FrontFace
from shelfpick.perception.masks import border_sides
from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.measure import Measured, RepairContext
from shelfpick.perception.repairs.planes import join_on_plane, largest_component, rect_fill


@dataclass(frozen=True, eq=False)
class Handover:
    """Part of mask i went to the pieces `used`: `rest` is left of the mask, `union` the
    pieces' joined face; `note` says so."""

    used: tuple[int, ...]
    rest: np.ndarray
    union: np.ndarray
    note: str


# (index, mask, its face, all masks, context) -> the handover, or None
Attempt = Callable[[int, np.ndarray, Measured, list, RepairContext], "Handover | None"]


def give_parts(masks: list[np.ndarray], ctx: RepairContext, least: int,
               attempt: Attempt) -> tuple[list[np.ndarray], list[str]]:
    """For each mask that is no type face and not cut by the image border (when there are at
    least `least` masks), `attempt` a handover; after a change the scan starts again."""
    out = [np.asarray(m, bool) for m in masks]
    notes: list[str] = []
    if len(out) < least:
        return out, notes
    i = 0
    while i < len(out):
        m = out[i]
        f = ctx.measure(m)
        done = None if f is None or f.err <= ctx.cat.tol or border_sides(m) else attempt(i, m, f, out, ctx)
        if done is None:
            i += 1
            continue
        notes.append(done.note)
        out = [o for j, o in enumerate(out) if j != i and j not in done.used] + [done.rest, done.union]
        i = 0
    return out, notes


def one_part(rest: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """(what is left, the specks cut off it) when `rest` is one 4-connected part holding
    >= 95% of its pixels (specks empty when it is whole); None when it falls apart."""
    big, several = largest_component(rest)
    if not several:
        return rest, np.zeros_like(rest)
    if count(big) < 0.95 * count(rest):
        return None
    return big, rest & ~big


def part_to_pieces(rest: np.ndarray, part: np.ndarray, grp: np.ndarray, face: FrontFace, i: int,
                   used: list[int], out: list[np.ndarray],
                   ctx: RepairContext) -> tuple[Measured, np.ndarray, Measured] | None:
    """(rest's face, the pieces `grp` joined with `part` on `face`, that face) when what is left
    of mask i is a type face filling its rectangle and the join is a type face too; else None."""
    cat = ctx.cat
    fr = ctx.measure_once(rest)
    if fr is None or fr.err > cat.tol or rect_fill(rest) < cat.join_fill:
        return None
    taken = rest.copy()
    for q, oq in enumerate(out):
        if q != i and q not in used:
            taken |= oq
    union, fill = join_on_plane(part, grp, face, taken, ctx)
    if fill < cat.join_fill:
        return None
    fu = ctx.measure_once(union)
    if fu is None or fu.err > cat.tol:
        return None
    return fr, union, fu
