"""The shelf a plan predicts after each of its steps, in the perceived scene's own coordinates.

The planner's preview (`Predictor.preview`) runs the plan in one sample world
and records every box's pose. That world's boxes sit at sampled depths and
were settled by the physics, so its poses are not the perceived ones; what it
predicts is how each box *moves*. `predicted_shelves` applies each box's
simulated rigid motion since the start of the plan to the box as perceived:
a box predicted to stay keeps its perceived pose exactly, so the console's
look after a step compares like with like (a camera against a camera).
Boxes the plan has taken out, that the simulation parked, or that it
predicts to fall out of the shelf (to the floor in front of it) are gone.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Any, Mapping, Sequence

from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Box, Scene, quat_to_matrix

Pose = tuple[tuple[float, float, float], tuple[float, float, float, float]]
_FAR = 5.0   # m: a pose this far from the shelf is a parked body, not a box on the shelf


def _qmul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def moved_box(box: Box, before: Pose, after: Pose) -> Box:
    """`box` carried along by the rigid motion that took a body from `before` to `after`."""
    (p0, q0), (p1, q1) = before, after
    dq = _qmul(q1, (q0[0], -q0[1], -q0[2], -q0[3]))
    r = quat_to_matrix(dq)
    rel = [box.position[i] - p0[i] for i in range(3)]
    pos = tuple(p1[i] + sum(r[i][j] * rel[j] for j in range(3)) for i in range(3))
    q = _qmul(dq, box.orientation)
    n = sum(c * c for c in q) ** 0.5
    return replace(box, position=pos, orientation=tuple(c / n for c in q))


def _frames(step: Any) -> Sequence:
    """Recorded frames of a StepResult or of its JSON (`to_json(frames=True)`)."""
    if isinstance(step, Mapping):
        return [(t, {k: (tuple(v[0]), tuple(v[1])) for k, v in poses.items()}) for t, poses in step.get("frames", [])]
    return getattr(step, "frames", ()) or ()


def start_poses(preview: Sequence[Any]) -> dict[str, Pose]:
    """The simulated pose of every box before the plan: the first frame of its first recorded step."""
    frames = _frames(preview[0]) if preview else ()
    return dict(frames[0][1]) if frames else {}


def on_shelf(pose: Pose) -> bool:
    """A simulated pose near the shelf (not a body the simulation parked far away)."""
    return _on_shelf(pose)


def _on_shelf(pose: Pose) -> bool:
    p = pose[0]
    return abs(p[0]) < _FAR and abs(p[1]) < _FAR and abs(p[2]) < _FAR


def inside(scene: Scene, box: Box) -> bool:
    """`box` stands within `scene`'s shelf as a scene file may hold it (Scene.check_bounds)."""

    try:
        scene.with_boxes([box]).check_bounds()
    except FormatError:
        return False
    return True


def predicted_shelves(scene: Scene, sequence: Sequence[str], preview: Sequence[Any],
                      start: Mapping[str, Pose] | None = None) -> list[Scene]:
    """The perceived `scene` after each step of `sequence`, as the recorded `preview` predicts it.

    `preview`: one recorded step per plan step (StepResult or its JSON with
    frames). `start`: the simulated poses the motion is measured from (default:
    the first frame of the first step, i.e. the shelf before the plan). A step
    without frames predicts that nothing else moved.
    """
    if start is None:
        start = start_poses(preview)
    out = []
    removed: set[str] = set()
    now: dict[str, Pose] = dict(start)    # each box's simulated pose after the latest step
    for k, box_id in enumerate(sequence):
        removed.add(box_id)
        frames = _frames(preview[k]) if k < len(preview) else ()
        if frames:
            now.update({b: pose for b, pose in frames[-1][1].items() if b in now})
        boxes = []
        for b in scene.boxes:
            if b.id in removed:
                continue
            if b.id not in now:
                boxes.append(b)     # the simulation did not record it: predicted to stay
            elif _on_shelf(now[b.id]):
                m = moved_box(b, start[b.id], now[b.id])
                if inside(scene, m):
                    boxes.append(m)   # else predicted to fall out of the shelf: gone from it
        out.append(scene.with_boxes(boxes))
    return out


def shelf_after(scene: Scene, sequence: Sequence[str], preview: Sequence[Any], step: int) -> Scene:
    """`predicted_shelves(...)[step]`."""
    return predicted_shelves(scene, sequence[:step + 1], preview[:step + 1])[step]


__all__ = ["predicted_shelves", "shelf_after", "moved_box", "sim_poses_after", "inside", "start_poses",
           "on_shelf"]


def sim_poses_after(preview: Sequence[Any], step: int) -> dict[str, Pose]:
    """The simulated pose of every recorded box after `step` (its last recorded pose until then)."""
    frames0 = _frames(preview[0]) if preview else ()
    now: dict[str, Pose] = dict(frames0[0][1]) if frames0 else {}
    for k in range(min(step + 1, len(preview))):
        frames = _frames(preview[k])
        if frames:
            now.update(frames[-1][1])
    return now
