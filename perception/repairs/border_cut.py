"""Faces cut by the image border: which of their sides the border cuts, and the face they are
completed to where the catalogue explains them."""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np

from shelfpick.perception.faces import FrontFace, face_axes
from shelfpick.perception.masks import border_pixels, border_sides
from shelfpick.perception.pixels import count
from shelfpick.perception.repairs.planes import coords
from shelfpick.perception.scene import Camera

if TYPE_CHECKING:
    from shelfpick.perception.catalogue import Catalogue


def cut_directions(face: FrontFace, mask: np.ndarray, camera: Camera, sides: tuple[str, ...] | None = None,
                   margin: int = 2) -> set[str]:
    """The face sides ("+x", "-x", "+z", "-z" on the face's width/height axes) that an image
    border cuts: per border the mask runs into, the side its border pixels lie on (their median
    cast onto the face plane, relative to the half extent)."""
    out: set[str] = set()
    for side in (border_sides(mask, margin) if sides is None else sides):
        px = border_pixels(mask, side, margin)
        if count(px) < 3:
            continue
        _, _, cx, cz = coords(face, px, camera)
        if not len(cx):
            continue
        rx = float(np.median(cx)) / max(face.width / 2, 1e-6)
        rz = float(np.median(cz)) / max(face.height / 2, 1e-6)
        if max(abs(rx), abs(rz)) < 0.25:
            continue        # border pixels in the middle of the face: cannot tell
        out.add(("+x" if rx > 0 else "-x") if abs(rx) >= abs(rz) else ("+z" if rz > 0 else "-z"))
    return out


def complete_cut_face(face: FrontFace, mask: np.ndarray, camera: Camera, cat: "Catalogue | None",
                      sides: tuple[str, ...] | None = None,
                      min_side: float = 0.02) -> tuple[FrontFace, set[str], str | None]:
    """A face cut by the image border, completed where the catalogue explains it.

    The face is at least as big as seen. Cut along one axis only (its other side seen whole),
    it becomes the smallest type face whose uncut side matches (within `tol`) and whose cut
    side is at least as long as seen, grown away from the border; otherwise it keeps its seen
    size, but no side under `min_side` (a strip along the border still stands for a box).
    Returns (face, cut directions, how it was completed: "type", "min" or None)."""
    cut = cut_directions(face, mask, camera, sides)
    w, h, how = _completed_size(face, cut, cat)
    w, h = max(w, min_side), max(h, min_side)
    if (w, h) == (face.width, face.height):
        return face, cut, None
    rot = face_axes(face)
    shift = np.zeros(3)
    for d in cut:
        col = rot[:, 0] if d[1] == "x" else rot[:, 2]
        grow = (w - face.width) if d[1] == "x" else (h - face.height)
        if (("+" + d[1]) in cut) and (("-" + d[1]) in cut):
            continue        # cut on both ends: grow about the centre
        shift += (1.0 if d[0] == "+" else -1.0) * col * grow / 2
    c = tuple(float(v) for v in np.asarray(face.center) + shift)
    return replace(face, center=c, width=float(w), height=float(h)), cut, how or "min"


def _completed_size(face: FrontFace, cut: set[str], cat: "Catalogue | None") -> tuple[float, float, str | None]:
    """(width, height, "type") of the smallest type face that explains a face cut along one
    axis, else the seen (width, height, None)."""
    w, h = face.width, face.height
    axes = {d[1] for d in cut}
    if cat is None or len(axes) != 1:
        return w, h, None
    ax = axes.pop()
    seen, other = (h, w) if ax == "z" else (w, h)
    cands = [(f[1], f[0]) if ax == "z" else (f[0], f[1]) for f in cat.faces]   # (cut side, uncut side)
    cands = [c for c in cands if abs(c[1] - other) <= cat.tol and c[0] >= seen - cat.tol]
    if not cands:
        return w, h, None
    full = max(min(cands)[0], seen)
    return (w, full, "type") if ax == "z" else (full, h, "type")
