"""A piece (a label, a tape band) that one mask on its plane surrounds goes to that mask."""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.masks import border_sides
from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.measure import Measured, RepairContext
from shelfpick.perception.repairs.planes import on_plane, plane_dist


def absorb_enclosed(masks: list[np.ndarray], ctx: RepairContext, ring_px: int = 3, enclosed: float = 0.75,
                    surround: float = 0.6) -> tuple[list[np.ndarray], list[str]]:
    """Give a piece (no type face) that another mask on its plane surrounds to that mask: a
    label or a tape band inside a face whose mask is itself a little off its type (it took a
    strip of the box below), so no join makes a type face of them. A box's face is never
    inside another box's face on one plane, so the piece needs no type to be explained.

    Surrounded: >= `enclosed` of the `ring_px` ring around the piece is that mask (counting only
    ring pixels of masks or on the mask's plane: the gap to the background at a box's edge does
    not count) and >= `surround` of the whole ring; the mask is at least twice the piece's area,
    and the piece lies on its plane. After each change the scan starts again."""
    out = [np.asarray(m, bool) for m in masks]
    notes: list[str] = []
    if len(out) < 2:
        return out, notes
    kernel = np.ones((2 * ring_px + 1,) * 2, np.uint8)
    while True:
        for i, m in enumerate(out):
            f = ctx.measure(m)
            if f is None or f.err <= ctx.cat.tol or border_sides(m):
                continue
            j = _host(i, f, out, ctx, kernel, enclosed, surround)
            if j is not None:
                host = ctx.measure(out[j]).face.size_cm
                notes.append(f"gave a {f.face.size_cm} piece inside a {host} mask to it")
                out[j] = out[j] | m
                out.pop(i)
                break
        else:
            return out, notes


def _host(i: int, f: Measured, out: list[np.ndarray], ctx: RepairContext, kernel: np.ndarray,
          enclosed: float, surround: float) -> int | None:
    """The mask that surrounds piece i on its plane (see `absorb_enclosed`), or None."""
    m = out[i]
    ring = (cv2.dilate(m.astype(np.uint8), kernel) > 0) & ~m
    if not ring.any():
        return None
    claimed = np.zeros_like(ring)
    for j, o in enumerate(out):
        if j != i:
            claimed |= ring & o
    for j, o in enumerate(out):
        if j == i or not (ring & o).any() or count(o) < 2 * count(m):
            continue
        fo = ctx.measure(o)
        if fo is None or plane_dist(fo.face, m, ctx) > ctx.cat.plane_tol:
            continue
        # the ring that counts: pixels of any mask, or on the mask's plane (a gap to the
        # background or a box further back around a face's edge does not); the mask itself
        # must lie all round it (a part of a face at its edge, beside the mask on one side
        # only, is no label)
        n = int((claimed | (ring & on_plane(fo.face, ring, ctx, ctx.cat.plane_tol))).sum())
        hit = count(ring & o)
        if n == 0 or hit < enclosed * n or hit < surround * count(ring):
            continue
        return j
    return None
