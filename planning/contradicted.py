"""Faces perception doubts (`perceived.contradicted`) in planning: a plan touching one is not
declared safe.

When the perceived faces of a shelf cannot all be right (an overlap no parting explains, a face
seen where another would hide it, a stack taller than the shelf), perception says so and marks
each box the contradiction names (perception/boxes.py `flag_contradicted`). The sample worlds
are built from those faces, so what they predict near such a box rests on geometry perception
itself says is wrong somewhere. The prediction is still made and shown; but a step whose pulled
box, or a box the prediction moves, is such a box or stands against one (within `CONTACT`
across the pull: beside, on or under it) makes the plan not safe, with the reason in
`plan.extra["contradicted"]`. A scene no camera made carries no such mark.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any, Sequence

from shelfpick.perception.scene import Box, Scene

if TYPE_CHECKING:  # pragma: no cover
    from shelfpick.planning.plan import StepPrediction

CONTACT = 0.01     # m across the pull (x, z) within which two boxes touch


def doubted(scene: Scene) -> list[str]:
    """The ids of the boxes perception marked as part of a contradiction, in scene order."""
    return [b.id for b in scene.boxes if b.contradicted]


def _across(b: Box) -> tuple[float, float, float, float]:
    cs = b.corners()
    xs, zs = [c[0] for c in cs], [c[2] for c in cs]
    return min(xs), max(xs), min(zs), max(zs)


def _touch(a: Box, b: Box) -> bool:
    p, q = _across(a), _across(b)
    return p[0] - CONTACT < q[1] and q[0] - CONTACT < p[1] and p[2] - CONTACT < q[3] and q[2] - CONTACT < p[3]


def _against(bid: str, boxes: dict[str, Box], named: list[str]) -> str | None:
    """The doubted box `bid` is or stands against, or None."""
    if bid in named:
        return bid
    if bid not in boxes:
        return None
    return next((d for d in named if d in boxes and _touch(boxes[bid], boxes[d])), None)


def touches(scene: Scene, sequence: Sequence[str], predicted: Sequence["StepPrediction"] = ()) -> list[str]:
    """Why the plan touches a doubted face, one line per (step, box); [] when it does not."""
    named = doubted(scene)
    if not named:
        return []
    boxes = {b.id: b for b in scene.boxes}
    moved = {i: p.moved for i, p in enumerate(predicted)}
    out = []
    for i, bid in enumerate(sequence):
        for who, what in [(bid, f"pulling {bid}")] + [(m, f"{m}, moved by pulling {bid},")
                                                       for m in moved.get(i, ()) if m != bid]:
            d = _against(who, boxes, named)
            if d is not None:
                how = "is" if d == who else f"touches {d},"
                out.append(f"step {i + 1}: {what} {how} a box whose perceived face cannot be right as seen")
    return out


def verdict(scene: Scene, sequence: Sequence[str], predicted: Sequence["StepPrediction"], safe: bool,
            extra: dict[str, Any]) -> tuple[bool, dict[str, Any]]:
    """(safe, extra) with the doubted faces' say: a plan that touches one is not safe, and
    `extra["contradicted"]` names them and what touched them (only for a scene that has any)."""
    named = doubted(scene)
    if not named:
        return safe, extra
    why = touches(scene, sequence, predicted)
    extra = {**extra, "contradicted": {"boxes": named, "touched": why}}
    return safe and not why, extra
