"""Re-cutting neighbouring masks that are no type faces along the faces' own seams: two
stacked cubes cut down their tape whose left halves and right halves merged."""
from __future__ import annotations

from dataclasses import replace

import numpy as np

from shelfpick.perception.masks import border_sides
from shelfpick.perception.repairs.measure import Measured, RepairContext, neighbour_pieces
from shelfpick.perception.repairs.planes import join_on_plane
from shelfpick.perception.repairs.splits import split_one


def regroup_pieces(masks: list[np.ndarray], ctx: RepairContext,
                   max_group: int = 4) -> tuple[list[np.ndarray], list[str]]:
    """Re-cut neighbouring masks that are no type faces along the faces' own seams: two stacked
    cubes, each cut down its vertical tape, whose left halves and right halves merged (two
    10x40 masks for two 20x20 faces); a face whose tape band gave its halves to the faces
    above and below.

    For a mask that is no type face and its neighbouring masks on its plane that are no type
    faces either (a pair first, then all of them, up to `max_group`): their union (with the
    unclaimed on-plane pixels between them) fills its rectangle >= `join_fill` and is cut by
    `split_faces`' rule (sides within `join_tol`: masks grown apart measure a little wide) into
    parts that are ALL type faces within `tol`; the masks become those parts. Nothing is done
    where a part would be no type face."""
    out = [np.asarray(m, bool) for m in masks]
    notes: list[str] = []
    if len(out) < 2:
        return out, notes
    # the parts of masks grown apart may measure a little wide: cut at `join_tol`, as for a join
    loose = replace(ctx, cat=replace(ctx.cat, tol=ctx.cat.join_tol), cache=None)
    tried = _Tried()
    i = 0
    while i < len(out):
        m = out[i]
        f = ctx.measure(m)
        done = None
        if f is not None and f.err > ctx.cat.tol and not border_sides(m):
            done = _first_regroup(i, f, out, ctx, loose, tried, max_group)
        if done is None:
            i += 1
            continue
        group, parts = done
        sizes = [ctx.measure(p).face.size_cm for p in parts]
        notes.append(f"re-cut {len(group)} masks that are no type faces "
                     f"({', '.join(ctx.measure(out[q]).face.size_cm for q in group)}) "
                     f"along their seams into {', '.join(sizes)} faces")
        out = [o for q, o in enumerate(out) if q not in group] + parts
        i = 0
    return out, notes


class _Tried:
    """The groups of masks already tried (by mask object; the masks are held, so their ids are
    not reused while this lives)."""

    def __init__(self) -> None:
        self._keys: set[frozenset[int]] = set()
        self._held: list[np.ndarray] = []

    def first_time(self, group: list[np.ndarray]) -> bool:
        key = frozenset(id(m) for m in group)
        if key in self._keys:
            return False
        self._keys.add(key)
        self._held.extend(group)
        return True


def _first_regroup(i: int, f: Measured, out: list[np.ndarray], ctx: RepairContext, loose: RepairContext,
                   tried: "_Tried", max_group: int):
    """The first group (mask i with one neighbouring piece on its plane, then with all of
    them) not tried before that re-cuts into type faces only: (indices, parts), else None."""
    near = neighbour_pieces(i, out, ctx, plane=f.face)
    groups = [[j] for j in near]
    if 2 <= len(near) <= max_group - 1:
        groups.append(near)
    for g in groups:
        if not tried.first_time([out[q] for q in [i] + g]):
            continue
        done = _regroup(i, g, out, f, ctx, loose)
        if done is not None:
            return done
    return None


def _regroup(i: int, g: list[int], out: list[np.ndarray], f: Measured, ctx: RepairContext,
             loose: RepairContext):
    """(indices of the masks, the type-face parts) when mask i and masks `g` re-cut into type
    faces only; else None. See `regroup_pieces`."""
    cat = ctx.cat
    group = [i] + list(g)
    rest = np.zeros_like(out[i])
    for q in g:
        rest |= out[q]
    taken = np.zeros_like(out[i])
    for q, o in enumerate(out):
        if q not in group:
            taken |= o
    union, fill = join_on_plane(out[i], rest, f.face, taken, ctx)
    if fill < cat.join_fill:
        return None
    fu = ctx.measure_once(union)
    if fu is None or fu.err <= cat.tol:
        return None         # a type face: `join_pieces`' business
    others = [o for q, o in enumerate(out) if q not in group]
    parts, _ = split_one(union, loose, 4, None, others)
    if len(parts) < 2 or len(parts) < len(group) - 1:
        return None
    for p in parts:
        fp = ctx.measure_once(p)
        if fp is None or fp.err > cat.tol:
            return None
    return group, parts
