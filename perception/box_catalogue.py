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

import itertools
import math
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from perception.faces import FrontFace
from perception.masks import scaled_px
from perception.repairs.bands import take_bridging_parts
from perception.repairs.enclosed import absorb_enclosed
from perception.repairs.joins import join_pieces
from perception.repairs.l_cuts import cut_l_shapes
from perception.repairs.measure import FaceCache, Measured, RepairContext
from perception.repairs.regroup import regroup_pieces
from perception.repairs.splits import split_faces
from perception.repairs.stepped import split_stepped_faces, take_stepped_parts
from perception.scene import BOX_TYPES, Camera

# the method's box types (w, d, h in metres): perception.scene's table
REFERENCE_TYPES: tuple[tuple[float, float, float], ...] = tuple(BOX_TYPES.values())


@dataclass(frozen=True)
class Catalogue:
    """Box types whose faces a front face may be; `tol` (m) is how close both sides must be."""

    types: tuple[tuple[float, float, float], ...] = REFERENCE_TYPES
    tol: float = 0.02
    join_tol: float = 0.025          # m: a joined union may be this far off a type face
    min_evidence: float = 5.0        # colour line/step along the split, in robust noise units ...
    depth_step: float = 0.004        # ... or a depth step (m) along the line counts as a seam
    min_share: float = 0.25         # used only when this share of the faces already are type faces
    max_join_gap_px: int = 12        # pieces this close (px) are neighbours (at REF_DEPTH, see `scaled`)
    l_margin_px: int = 10            # an L-cut leaves at least this many rows/columns on each side
    join_fill: float = 0.85          # a joined union fills its min-area rectangle this well ...
    join_fill_loose: float = 0.75    # ... or this well when it is a type face within `tol`
    plane_tol: float = 0.012         # m: a joined piece lies this close to its neighbour's plane
    row_margin: float = 0.05         # m: a mask this far off every type face may be a row of 3+
    weak_evidence: float = 0.5       # seam score enough to split such a mask into exactly two type faces
    max_depth: float | None = None   # m: a face whose box is deeper than this cannot face the front
    faces: tuple[tuple[float, float], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        fs = set()
        for t in self.types:
            for i, j in itertools.permutations(range(3), 2):
                d = float(t[3 - i - j])
                if self.max_depth is not None and d > self.max_depth + 1e-9:
                    continue
                fs.add((round(float(t[i]), 4), round(float(t[j]), 4)))
        object.__setattr__(self, "faces", tuple(sorted(fs)))

    def within(self, depth: float | None, overhang: float = 0.05) -> "Catalogue":
        """Only the faces a box can show in a shelf this deep (its third side fits, sticking out
        of the front by up to `overhang`, as the planner's shelves allow): in a 30 cm shelf the
        50x17x17 box never shows its 17x17 end, so a third of its 17x50 face cut off by tape is
        no type face; the 23x31x25 box may show 23x25 (31 cm deep, 1 cm out)."""
        return self if depth is None else replace(self, max_depth=float(depth) + overhang)

    def scaled(self, scale: float) -> "Catalogue":
        """The pixel thresholds at `scale` (masks.pixel_scale: f / depth relative to the tuning
        distance), so a camera further back joins and cuts what one at ~1 m would."""
        if scale == 1.0:
            return self
        return replace(self, max_join_gap_px=scaled_px(self.max_join_gap_px, scale, 2),
                       l_margin_px=scaled_px(self.l_margin_px, scale, 3))

    def error(self, width: float, height: float) -> float:
        """Largest side error (m) to the closest type face."""
        if not self.faces:
            return math.inf
        return min(max(abs(width - w), abs(height - h)) for w, h in self.faces)

    def matches(self, width: float, height: float, tol: float | None = None) -> bool:
        return self.error(width, height) <= (self.tol if tol is None else tol)

    def error_cut(self, width: float, height: float, cut_axes: set[str] | frozenset[str] = frozenset()) -> float:
        """`error` for a face cut by the image border along `cut_axes` ("x", "z"): a cut side
        is only a lower bound, so it counts only where it is longer than the type's side."""
        if not self.faces:
            return math.inf
        return min(max(max(0.0, width - w) if "x" in cut_axes else abs(width - w),
                       max(0.0, height - h) if "z" in cut_axes else abs(height - h)) for w, h in self.faces)

    def fits(self, width: float, height: float) -> bool:
        """Whether a face of this size fits inside some type face (a part of one)."""
        return any(width <= w + self.tol and height <= h + self.tol for w, h in self.faces)

    def composable(self, width: float, height: float, axis: int, parts: int = 2,
                   staggered: bool = False) -> bool:
        """Whether a face of this size is `parts` type faces in a row: stacked (axis 1, heights
        add up, the widest as wide as it) or side by side (axis 0, widths add up).
        `staggered`: the faces may be offset across the row (a stack of boxes pushed left and
        right), so the row spans at least its widest face and at most all of them side by side."""
        for combo in itertools.combinations_with_replacement(self.faces, parts):
            along = sum(f[1] if axis == 1 else f[0] for f in combo)
            acr = [f[0] if axis == 1 else f[1] for f in combo]
            total, span = (height, width) if axis == 1 else (width, height)
            if abs(along - total) > 1.5 * self.tol:
                continue
            if abs(max(acr) - span) <= self.tol or (
                    staggered and max(acr) - self.tol <= span <= sum(acr) + self.tol):
                return True
        return False

    @property
    def sides(self) -> tuple[float, ...]:
        return tuple(sorted({s for f in self.faces for s in f}))

    def to_json(self) -> dict:
        return {"types": [list(t) for t in self.types], "tol": self.tol}


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
    area = [float(f.mask.sum()) for f in ok]
    share = max(sum(f.err <= cat.tol for f in ok) / max(len(ok), 1),
                sum(a for f, a in zip(ok, area) if f.err <= cat.tol) / max(sum(area), 1.0))
    return share >= cat.min_share


def catalogue_applies(faces: list[FrontFace | None], masks: list[np.ndarray], cat: Catalogue) -> bool:
    """Whether a capture whose masks measured as `faces` (None where not measured) shows boxes
    of these types (see `apply_catalogue`): where it does not (other stock, the neura pallet),
    a face cut by the image border is not completed to a type face either."""
    return _applies([None if f is None else Measured(np.asarray(m, bool), f, cat.error(f.width, f.height))
                     for f, m in zip(faces, masks)], cat)
