"""Known box types: the faces a front face may be, and how close counts (`Catalogue`).

A warehouse usually stocks a few box types (the method's: 23x31x25, 20x20x20 and 50x17x17
cm), so a front face is one of a few rectangles. The mask repairs (perception/repairs/,
run by `box_catalogue.apply_catalogue`) act only where the catalogue explains the result.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

from shelfpick.perception.masks import scaled_px
from shelfpick.perception.scene import BOX_TYPES

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
    gap_off: float = 0.04            # m: a band across a union whose pixels mostly lie this far off
    gap_share: float = 0.5           # its plane (more than this share) is a gap: no join across it
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
