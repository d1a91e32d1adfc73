"""How precisely a shelf's front faces were measured, read from the faces themselves.

A box rests on the shelf floor or on the box below it, so in a shelf measured
exactly the bottom edge of each front face meets the floor or the top edge of
a face under it. Perception error opens gaps and overlaps there, about as large
as the error. The median of those residuals says how much to trust a face's size
and place, with no camera model and no box catalogue: exact faces (a scene file,
a simulated camera) give well under a millimetre, 1 cm of perception error about
a centimetre. The sample worlds draw each face's width, height and place along
its normal within that, up to the model's in-plane face error (docs/physics.md,
"Face error read from the shelf").
"""
from __future__ import annotations

import statistics
from dataclasses import replace

from perception.scene import Box, Scene
from planning.uncertainty import Uncertainty, face_corners

EXACT = 0.001          # m: residuals below a millimetre are a measurement as exact as it gets
REACH = 0.05           # m: a face further than this from any support rests on something unseen
OVERLAP = 0.03         # m: a face under this one must share this much width to carry it

Outline = list[tuple[float, float]]


def outline(box: Box) -> Outline:
    """The front face as a polygon in the shelf's (x, z) plane, corners in order around it."""
    f = face_corners(box)   # (-x,-z), (-x,+z), (+x,-z), (+x,+z) in the box's frame
    return [(c[0], c[2]) for c in (f[0], f[2], f[3], f[1])]


def _edge_z(poly: Outline, x: float, top: bool) -> float:
    """z of the polygon's top (or bottom) boundary at `x`, which lies within its x span."""
    zs = []
    for (xa, za), (xb, zb) in zip(poly, poly[1:] + poly[:1]):
        if min(xa, xb) - 1e-9 <= x <= max(xa, xb) + 1e-9:
            zs += [za, zb] if abs(xb - xa) < 1e-9 else [za + (zb - za) * (x - xa) / (xb - xa)]
    return max(zs) if top else min(zs)


def vertical_gap(upper: Outline, lower: Outline) -> float | None:
    """Smallest height of `upper`'s bottom above `lower`'s top where both span at least
    `OVERLAP` of the same x (negative: they overlap); None when they share less width.
    Both boundaries are piecewise linear, so the smallest gap is at a corner's x."""
    ux, lx = [p[0] for p in upper], [p[0] for p in lower]
    a, b = max(min(ux), min(lx)), min(max(ux), max(lx))
    if b - a < OVERLAP:
        return None
    xs = [a, b] + [x for x in ux + lx if a < x < b]
    return min(_edge_z(upper, x, False) - _edge_z(lower, x, True) for x in xs)


def support_residuals(scene: Scene) -> list[float]:
    """|gap| between each observed face and the support nearest under or over its bottom
    edge (the floor, or a face sharing its width), for the faces within `REACH` of one."""
    faces = {b.id: outline(b) for b in scene.boxes if not b.depth_known}
    out = []
    for i, poly in faces.items():
        gaps = [min(z for _, z in poly)]   # the floor is z = 0
        gaps += [g for j, other in faces.items() if j != i
                 if (g := vertical_gap(poly, other)) is not None]
        nearest = min(gaps, key=abs)
        if abs(nearest) <= REACH:
            out.append(abs(nearest))
    return out


def measured_face_error(scene: Scene) -> float:
    """The median support residual of the scene's observed faces, metres (0 with none)."""
    res = support_residuals(scene)
    return statistics.median(res) if res else 0.0


def fit_to_scene(model: Uncertainty, scene: Scene) -> Uncertainty:
    """`model` with its face size and depth errors read from `scene` when it asks for that
    (`fit_faces`): the measured error, capped at the in-plane `face_error`, or 0 below `EXACT`."""
    if not model.fit_faces:
        return model
    e = measured_face_error(scene)
    e = 0.0 if e < EXACT else min(e, model.face_error)
    return replace(model, face_size_error=e, face_depth_error=e, fit_faces=False)
