"""A tape band across a face, merged with the flush face above it: the face comes back from
its two pieces and the part of the merged mask that lies inside their rectangle."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.measure import Measured, RepairContext, neighbour_pieces
from shelfpick.perception.repairs.parts import Handover, give_parts, one_part, part_to_pieces
from shelfpick.perception.repairs.planes import min_area_rect


def take_bridging_parts(masks: list[np.ndarray], ctx: RepairContext) -> tuple[list[np.ndarray], list[str]]:
    """Give a face back the part of another mask that lies inside its rectangle: a tape band
    across a face, merged with the flush face above it (same colour, same plane), leaves the
    face as two pieces on either side of the band and a T-shaped mask that is no type face.

    For a mask that is no type face with >= 2 neighbouring pieces (no type faces, on its
    plane): the pieces' joint rectangle is their face; the mask's pixels inside it go to the
    pieces only when the pieces and that part join into a type face filling its rectangle
    >= `join_fill` AND what is left of the mask is a type face (within `tol`)."""
    return give_parts(masks, ctx, 3, _bridge_attempt)


def _bridge_attempt(i: int, m: np.ndarray, f: Measured, out: list[np.ndarray],
                    ctx: RepairContext) -> Handover | None:
    pieces = neighbour_pieces(i, out, ctx, plane=f.face)
    done = _bridge(m, i, pieces, out, ctx) if len(pieces) >= 2 else None
    if done is None:
        return None
    rest, union, fr, fu = done
    return Handover(tuple(pieces), rest, union,
                    f"gave the part of a {f.face.size_cm} mask inside {len(pieces)} pieces' "
                    f"rectangle to them: {fu.face.size_cm} and {fr.face.size_cm}")


def _bridge(m: np.ndarray, i: int, pieces: list[int], out: list[np.ndarray], ctx: RepairContext):
    """(rest of m, joined face mask, their faces) or None; see `take_bridging_parts`."""
    grp = np.zeros_like(m)
    for j in pieces:
        grp |= out[j]
    part = m & (min_area_rect(grp) > 0)
    rest = m & ~part
    if count(part) < 0.05 * count(m) or count(rest) < 0.3 * count(m):
        return None
    # what is left must stay one piece (drop a thin fringe along the rectangle's edge)
    kept = one_part(rest)
    if kept is None:
        return None
    rest, fringe = kept
    part = part | fringe
    fg = ctx.measure(out[pieces[0]])
    done = part_to_pieces(rest, part, grp, fg.face, i, pieces, out, ctx)
    if done is None:
        return None
    fr, union, fu = done
    return rest, union, fr, fu
