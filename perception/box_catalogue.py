"""Known box types, and the mask repairs they explain (perception/repairs/).

A warehouse usually stocks a few box types (the method's: 23x31x25, 20x20x20
and 50x17x17 cm), so a front face is one of a few rectangles. Masks fail
that test in typical ways:
- a piece cut off a face (a label or tape at its border, one side of a tape
  band) is too small to be a face; joined with the neighbour on its plane the
  union is a known face (`repairs.joins`);
- two flush boxes of one colour (stacked, or side by side) with a faint seam
  merge into one mask whose size is no type face, but which splits at one line
  into two type faces; the seam shows as a line of colour edges (and/or a small
  depth step) right there (`repairs.splits`, `repairs.seams`);
- an L of one box's strip and another's end (`repairs.l_cuts`), a face cut by
  a tape band or a depth step whose part went to the box beside it
  (`repairs.bands`, `repairs.stepped`), halves merged crosswise
  (`repairs.regroup`), a label inside a face (`repairs.enclosed`).
Every repair only acts when the catalogue explains the result, within `tol`, so
a capture of other boxes (real data) is left as it is; the catalogue is a
parameter (`Catalogue(types=...)`), the reference types are the default.
`apply_catalogue` runs the repairs, each a step `(masks, context) -> (masks, notes)`, and
returns the masks, their faces and the notes.
"""
from __future__ import annotations

from typing import Callable

import numpy as np

from shelfpick.perception.catalogue import REFERENCE_TYPES, Catalogue  # noqa: F401 - re-exported
from shelfpick.perception.faces import FrontFace
from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.bands import take_bridging_parts
from shelfpick.perception.repairs.enclosed import absorb_enclosed
from shelfpick.perception.repairs.joins import join_pieces
from shelfpick.perception.repairs.l_cuts import cut_l_shapes
from shelfpick.perception.repairs.measure import FaceCache, Measured, RepairContext
from shelfpick.perception.repairs.regroup import regroup_pieces
from shelfpick.perception.repairs.splits import split_faces
from shelfpick.perception.repairs.stepped import split_stepped_faces, take_stepped_parts
from shelfpick.perception.scene import Camera

# a repair: the masks in, the masks out and what it changed (one line each)
Step = Callable[[list[np.ndarray], RepairContext], tuple[list[np.ndarray], list[str]]]


def _split_and_cut(masks: list[np.ndarray], ctx: RepairContext) -> tuple[list[np.ndarray], list[str]]:
    """`split_faces`, then `cut_l_shapes`: an L-cut's rest may be a row of faces the first split
    saw merged (split again), and a cut piece may join its own face's rest, a row cut into faces
    may leave a piece of a face beside its rest (joined again)."""
    n = len(masks)
    masks, notes = split_faces(masks, ctx)
    before = list(masks)
    masks, cut = cut_l_shapes(masks, ctx)
    if cut:
        masks, split = split_faces(masks, ctx, only=[m for m in masks if not any(m is b for b in before)])
        cut += split
    if len(masks) > n or cut:
        masks, joined = join_pieces(masks, ctx)
        cut += joined
    return masks, notes + cut


def _regroup_and_join(masks: list[np.ndarray], ctx: RepairContext) -> tuple[list[np.ndarray], list[str]]:
    """`regroup_pieces`, then, if it re-cut anything, `join_pieces`: a piece beside a re-cut
    face (a label, a tape quarter) may join it now."""
    masks, notes = regroup_pieces(masks, ctx)
    if notes:
        masks, joined = join_pieces(masks, ctx)
        notes += joined
    return masks, notes


STEPS: tuple[Step, ...] = (join_pieces, _split_and_cut, split_stepped_faces, take_bridging_parts,
                           take_stepped_parts, _regroup_and_join, absorb_enclosed)


def apply_catalogue(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, rgb: np.ndarray | None,
                    cat: Catalogue) -> tuple[list[np.ndarray], list[FrontFace | None], list[str]]:
    """The masks repaired by `STEPS` in order; their measured faces (None where a mask cannot
    be measured), so the pipeline need not measure them again; and what was changed, one line
    each. A capture where the types do not explain the faces is left alone (no notes)."""
    ctx = RepairContext(depth, camera, cat, rgb, FaceCache())
    masks = [np.asarray(m, bool) for m in masks]
    measured = [ctx.measure(m) for m in masks]
    notes: list[str] = []
    if _applies(measured, cat):
        for step in STEPS:
            masks, said = step(masks, ctx)
            notes += said
        measured = [ctx.measure(m) for m in masks]
    # (not a capture of these box types, e.g. another warehouse or real data: left alone)
    return masks, [None if f is None else f.face for f in measured], notes


def _applies(measured: list[Measured | None], cat: Catalogue) -> bool:
    """Whether at least `min_share` of the measured faces are type faces, by count or by area
    (a face cut into many pieces by a tape cross must not outvote the faces around it)."""
    ok = [f for f in measured if f is not None]
    area = [float(count(f.mask)) for f in ok]
    share = max(sum(f.err <= cat.tol for f in ok) / max(len(ok), 1),
                sum(a for f, a in zip(ok, area) if f.err <= cat.tol) / max(sum(area), 1.0))
    return share >= cat.min_share


def catalogue_applies(faces: list[FrontFace | None], masks: list[np.ndarray], cat: Catalogue) -> bool:
    """Whether a capture whose masks measured as `faces` (None where not measured) shows boxes
    of these types (see `apply_catalogue`): where it does not (other stock, the neura pallet),
    a face cut by the image border is not completed to a type face either."""
    return _applies([None if f is None else Measured(np.asarray(m, bool), f, cat.error(f.width, f.height))
                     for f, m in zip(faces, masks)], cat)
