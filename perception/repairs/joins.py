"""Joining pieces of one face: a label, tape end or flap cut off a face is joined back to the
neighbour on its plane when the union is a type face (and fills its rectangle)."""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from shelfpick.perception.masks import border_sides
from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.border_cut import cut_directions
from shelfpick.perception.repairs.crop import Near
from shelfpick.perception.repairs.measure import Measured, RepairContext
from shelfpick.perception.repairs.planes import band_trim, join_on_plane, plane_dist


@dataclass(frozen=True, eq=False)
class _Join:
    """Mask `into` becomes the joined face `face` (error `err`); the masks in `dead` are gone."""

    into: int
    face: Measured
    err: float
    dead: tuple[int, ...] = ()


class _Pieces:
    """The masks of one `join_pieces` call: their measured faces, image borders, errors to the
    closest type face, and which are still there. A face cut by the image border is only a
    lower bound of its size along the cut: its error counts a cut side only where it is too
    long, and it joins only pieces cut by the same border."""

    def __init__(self, masks: list[np.ndarray], ctx: RepairContext) -> None:
        self.ctx, self.cat = ctx, ctx.cat
        self.masks = [np.asarray(m, bool) for m in masks]
        self.faces = [ctx.measure(m) for m in self.masks]
        self.alive = [f is not None for f in self.faces]
        self.sides = [border_sides(m) for m in self.masks]
        self.errs = [self.err(f, m, sd) if f is not None else math.inf
                     for f, m, sd in zip(self.faces, self.masks, self.sides)]

    def err(self, fc: Measured, m: np.ndarray, sd: tuple[str, ...]) -> float:
        if not sd:
            return fc.err
        axes = {d[1] for d in cut_directions(fc.face, m, self.ctx.camera, sd)}
        return self.cat.error_cut(fc.face.width, fc.face.height, axes)

    def union_err(self, fu: Measured) -> float:
        return self.err(fu, fu.mask, border_sides(fu.mask))

    def same_border(self, i: int, j: int) -> bool:
        """Neither is cut by the image border, or both by one same border."""
        return not ((self.sides[i] or self.sides[j]) and not set(self.sides[i]) & set(self.sides[j]))

    def taken(self, but: set[int]) -> np.ndarray:
        """The pixels of the masks still there, but those in `but`."""
        out = np.zeros_like(self.masks[0])
        for q in range(len(self.masks)):
            if self.alive[q] and q not in but:
                out |= self.masks[q]
        return out

    def apply(self, i: int, join: _Join) -> None:
        """Piece i (and the join's dead) are gone; the joined face takes the join's mask."""
        j, fu = join.into, join.face
        for q in join.dead:
            self.alive[q] = False
        self.masks[j], self.faces[j], self.sides[j], self.errs[j] = fu.mask, fu, border_sides(fu.mask), join.err
        self.alive[i] = False

    def kept(self) -> list[np.ndarray]:
        return [m for m, a in zip(self.masks, self.alive) if a]


def join_pieces(masks: list[np.ndarray], ctx: RepairContext) -> tuple[list[np.ndarray], list[str]]:
    """Join a piece that is no type face to the neighbour on its plane when the union is one
    (and fills its rectangle): a label, tape end or flap cut off a face. Pieces are tried
    smallest first; after each join the scan starts again."""
    if len(masks) < 2:
        return masks, []
    p = _Pieces(masks, ctx)
    notes: list[str] = []
    while True:
        note = _join_a_piece(p)
        if note is None:     # a cross measured as the whole face, its quarters as pieces
            note = _join_a_cross(p)
        if note is None:
            return p.kept(), notes
        notes.append(note)


def _join_a_piece(p: _Pieces) -> str | None:
    """The first piece (smallest first) that joins: to one neighbour, else as a group with all
    its neighbouring pieces, else with a neighbour that is a type face by chance."""
    cat = p.cat
    order = sorted((i for i in range(len(p.masks)) if p.alive[i] and p.errs[i] > cat.tol),
                   key=lambda i: count(p.masks[i]))
    for i in order:
        near = p.ctx.near(p.masks[i])
        best = _pair_join(p, i, near)
        if best is None:
            best = _group_join(p, i)
        if best is None:       # a face cut into a row of pieces, i at one end
            best = _chain_join(p, i)
        if best is None:       # a piece of the cross that measures as a type face by chance
            best = _chance_join(p, i, near)
        if best is None:
            continue
        note = f"joined a {p.faces[i].face.size_cm} piece to its neighbour: {best.face.face.size_cm}"
        p.apply(i, best)
        return note
    return None


def _join_a_cross(p: _Pieces) -> str | None:
    """The largest type face that joins all its neighbouring pieces (a tape cross measured as
    the whole face, its quarters as pieces)."""
    for i in sorted((i for i in range(len(p.masks)) if p.alive[i] and p.errs[i] <= p.cat.tol),
                    key=lambda i: -count(p.masks[i])):
        g = _group_join(p, i)
        if g is None:
            continue
        p.apply(i, g)
        return f"joined the pieces of a face cut in several (a tape cross): {g.face.face.size_cm}"
    return None


def _pair_join(p: _Pieces, i: int, near: Near) -> _Join | None:
    """The best neighbour j of piece i on j's plane whose union with it is a type face, or
    (both being pieces) still fits inside one: a face cut into several pieces by tape and
    labels is joined step by step."""
    cat, masks = p.cat, p.masks
    best = None
    for j in range(len(masks)):
        if j == i or not p.alive[j] or not near.touches(masks[j]) or not p.same_border(i, j):
            continue
        if plane_dist(p.faces[j].face, masks[i], p.ctx) > cat.plane_tol:
            continue
        union, fill = join_on_plane(masks[i], masks[j], p.faces[j].face, p.taken({i, j}), p.ctx)
        if fill < cat.join_fill_loose:
            continue
        fu = p.ctx.measure(union)
        if fu is None:
            continue
        eu = p.union_err(fu)
        # a rectangle, or (a third piece still missing) a type face to within `tol`
        if fill < cat.join_fill and eu > cat.tol:
            continue
        if eu > cat.join_tol and not (p.errs[j] > cat.tol and cat.fits(fu.face.width, fu.face.height)):
            continue
        if best is None or (eu > cat.join_tol, eu) < (best.err > cat.join_tol, best.err):
            best = _Join(j, fu, eu)
    return best


def _chance_join(p: _Pieces, i: int, near: Near) -> _Join | None:
    """A group join of piece i with a neighbour on its plane that is a type face by chance."""
    for t in range(len(p.masks)):
        if t == i or not p.alive[t] or p.errs[t] > p.cat.tol or not near.touches(p.masks[t]) \
                or not p.same_border(i, t) \
                or plane_dist(p.faces[i].face, p.masks[t], p.ctx) > p.cat.plane_tol:
            continue
        best = _group_join(p, i, extra=t)
        if best is not None:
            return best
    return None


def _on_plane_pieces(p: _Pieces, i: int, of: int) -> list[int]:
    """The pieces (no type face) still there that touch mask `of` and lie on piece i's plane."""
    near = p.ctx.near(p.masks[of])
    return [j for j in range(len(p.masks))
            if j != i and p.alive[j] and p.errs[j] > p.cat.tol and near.touches(p.masks[j])
            and p.same_border(i, j) and plane_dist(p.faces[i].face, p.masks[j], p.ctx) <= p.cat.plane_tol]


def _chain_join(p: _Pieces, i: int) -> _Join | None:
    """The group join over every piece reachable from piece i through touching pieces on its
    plane: a 50x17 face cut by its tape and a label into a row, whose end piece touches only
    its neighbour (labels 31004: without it the end piece took the flush cube beside it as a
    chance type face). Tried only where the chain reaches past i's own neighbours."""
    own = _on_plane_pieces(p, i, i)
    chain, todo = list(own), list(own)
    while todo:
        for j in _on_plane_pieces(p, i, todo.pop()):
            if j not in chain:
                chain.append(j)
                todo.append(j)
    return _group_join(p, i, chain=chain) if len(chain) > len(own) else None


def _group_join(p: _Pieces, i: int, extra: int | None = None,
                chain: list[int] | None = None) -> _Join | None:
    """A face cut into 3+ pieces (a wide tape cross): no two of them fill a rectangle, but
    mask i (a piece, or the cross itself, which may measure as the whole face) and ALL its
    on-plane neighbouring pieces do, and make a type face. `extra`: one more neighbour that
    measures as a type face by chance (a quarter of a 50x17 face cut by a tape cross can
    measure 20x20), counted only within the band the pieces span across it (it may hold a
    strip of the flush box beside the cut face); the union must then be a type face within
    `tol`, and one piece is enough. `chain`: the pieces to join instead of i's neighbours."""
    cat, masks = p.cat, p.masks
    group = list(chain) if chain is not None else _on_plane_pieces(p, i, i)
    if extra is not None:
        group.append(extra)
    if len(group) < (1 if extra is not None else 2):
        return None
    rest = _group_mask(p, i, group, extra)
    if rest is None:
        return None
    union, fill = join_on_plane(masks[i], rest, p.faces[i].face, p.taken({i} | set(group)), p.ctx)
    if fill < cat.join_fill:
        return None
    fu = p.ctx.measure(union)
    if fu is None:
        return None
    eu = p.union_err(fu)
    if eu > (cat.join_tol if extra is None else cat.tol):
        return None
    if p.errs[i] <= cat.tol and max(abs(fu.face.width - p.faces[i].face.width),
                                    abs(fu.face.height - p.faces[i].face.height)) > cat.tol:
        return None       # a type face takes pieces only inside its own extent (its arms)
    return _Join(group[0], fu, eu, tuple(group[1:]))


def _group_mask(p: _Pieces, i: int, group: list[int], extra: int | None) -> np.ndarray | None:
    """The union of the group's masks; the chance type face `extra` may reach past the cut face
    into the flush box beside it, so it counts only within the band the pieces span across it
    (on either face axis), None when there is no such band."""
    masks = p.masks
    rest = np.zeros_like(masks[i])
    for j in group:
        rest |= masks[j]
    if extra is None:
        return rest
    rest = band_trim(masks[i] | rest & ~masks[extra], masks[extra], p.faces[extra].face, p.ctx.camera)
    if rest is None:
        return None
    for j in group:
        if j != extra:
            rest |= masks[j]
    return rest
