"""Unexplained matter (`Scene.unexplained`) in planning: an obstacle in every sample world,
and a plan that touches it is not declared safe.

Perception reports matter the depth image shows inside the shelf that no perceived box
explains (perception/unexplained.py). What it is, how heavy, how deep: nobody knows. So:

- every sample world holds it as a static obstacle: each column of its seen surface, grown
  by the tolerance perception explained its edges away with (`EXPLAIN_TOL`), from its
  nearest seen point back to the back wall (the most it may reach), cut back where it would
  run into a box of that world; boxes may rest on it and are stopped by it;
- a static obstacle never falls, so physics cannot say what pulling a box next to it, or
  under it, does to it: a step whose pulled box, or a box the prediction moves, comes within
  `TOUCH_MARGIN` of a region (in the x-z plane, where the pull sweeps: every region reaches
  back to the wall) makes the plan not safe, with the reason in `plan.extra["unexplained"]`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

from shelfpick.perception.scene import EXPLAIN_TOL, FRONT_REACH, Box, Scene, Unexplained

if TYPE_CHECKING:  # pragma: no cover
    from shelfpick.planning.plan import StepPrediction

# a box within this much (m) of a region's seen surface, across the pull, touches it: perception
# leaves EXPLAIN_TOL of unexplained matter next to a box unseen, and 1 cm more is contact
TOUCH_MARGIN = EXPLAIN_TOL + 0.01
_THIN = 0.005          # m: an obstacle cut thinner than this is left out (a box stands there)

Rect = tuple[float, float, float, float, float, float]   # x0, x1, y0, y1, z0, z1


def _aabb(b: Box) -> Rect:
    cs = b.corners()
    xs, ys, zs = ([c[k] for c in cs] for k in range(3))
    return min(xs), max(xs), min(ys), max(ys), min(zs), max(zs)


def _cut(o: list[float], b: Rect) -> list[float] | None:
    """The obstacle `o` (x0, x1, y0, y1, z0, z1) cut back out of box `b` along the axis that
    costs it least; None when what is left is thinner than `_THIN`."""
    if not all(o[2 * k] < b[2 * k + 1] and b[2 * k] < o[2 * k + 1] for k in range(3)):
        return o
    options = []
    for k in (0, 2):   # sideways or up/down: move the obstacle's near edge to the box's side
        options.append((o[2 * k + 1] - b[2 * k], 2 * k + 1, b[2 * k]))       # keep the part below/left
        options.append((b[2 * k + 1] - o[2 * k], 2 * k, b[2 * k + 1]))       # keep the part above/right
    options.append((o[3] - b[2], 3, b[2]))      # matter in front of a box: ends at its front
    _, i, v = min(options)
    out = list(o)
    out[i] = v
    if min(out[1] - out[0], out[3] - out[2], out[5] - out[4]) < _THIN:
        return None
    return out


def obstacles(scene: Scene) -> list[tuple[str, tuple[float, float, float], tuple[float, float, float]]]:
    """(name, half extents, centre) of every static body standing in for the scene's unexplained
    matter, cut back out of the scene's boxes (the boxes of one sample world)."""
    s = scene.shelf
    boxes = [_aabb(b) for b in scene.boxes]
    out = []
    for u in scene.unexplained or ():
        for x0, x1, z0, z1, y in u.columns:
            o: list[float] | None = [max(-s.width / 2, x0 - EXPLAIN_TOL), min(s.width / 2, x1 + EXPLAIN_TOL),
                                     max(-FRONT_REACH, min(y, s.depth - _THIN)), s.depth,
                                     max(0.0, z0 - EXPLAIN_TOL), min(s.height, z1 + EXPLAIN_TOL)]
            for b in boxes:
                o = _cut(o, b) if o is not None else None
            if o is None or min(o[1] - o[0], o[3] - o[2], o[5] - o[4]) < _THIN:
                continue
            half = ((o[1] - o[0]) / 2, (o[3] - o[2]) / 2, (o[5] - o[4]) / 2)
            centre = ((o[0] + o[1]) / 2, (o[2] + o[3]) / 2, (o[4] + o[5]) / 2)
            out.append((f"unexplained {u.id}", half, centre))
    return out


def near(b: Box, u: Unexplained, margin: float = TOUCH_MARGIN) -> bool:
    """Whether box `b` comes within `margin` of region `u`'s seen surface across the pull (x, z)."""
    x0, x1, _, _, z0, z1 = _aabb(b)
    return any(c[0] - margin < x1 and x0 < c[1] + margin and c[2] - margin < z1 and z0 < c[3] + margin
               for c in u.columns)


def touches(scene: Scene, sequence: Sequence[str], predicted: Sequence["StepPrediction"] = ()) -> list[str]:
    """Why the plan touches unexplained matter, one line per (step, box, region); [] when it does not."""
    regions = scene.unexplained or ()
    if not regions:
        return []
    boxes = {b.id: b for b in scene.boxes}
    moved = {i: p.moved for i, p in enumerate(predicted)}
    out = []
    for i, bid in enumerate(sequence):
        for u in regions:
            if bid in boxes and near(boxes[bid], u):
                out.append(f"step {i + 1}: pulling {bid} touches unexplained matter {u.id}")
            for m in moved.get(i, ()):
                if m != bid and m in boxes and near(boxes[m], u):
                    out.append(f"step {i + 1}: {m}, moved by pulling {bid}, touches unexplained matter {u.id}")
    return out


def verdict(scene: Scene, sequence: Sequence[str], predicted: Sequence["StepPrediction"], safe: bool,
            extra: dict[str, Any]) -> tuple[bool, dict[str, Any]]:
    """(safe, extra) with the unexplained matter's say: a plan that touches it is not safe, and
    `extra["unexplained"]` names the regions and what touched them (only for a scene that has any)."""
    regions = scene.unexplained or ()
    if not regions:
        return safe, extra
    why = touches(scene, sequence, predicted)
    extra = {**extra, "unexplained": {"regions": [u.id for u in regions], "touched": why}}
    return safe and not why, extra
