"""After a held step: the rest of the held plan in the new capture's ids (the `continue` offer)."""
from __future__ import annotations

from dataclasses import replace
from typing import TYPE_CHECKING, Any, Mapping

from shelfpick.perception.scene import Scene
from shelfpick.planning.plan import Plan

from shelfpick.console.workflow.run_json import step_json
from shelfpick.console.workflow.state import PlanEntry

if TYPE_CHECKING:
    from shelfpick.console.workflow.verify import Verification
    from shelfpick.console.workflow.state import PreviewStep


def mapped_target(plan: Plan, v: Verification, scene: Scene) -> str | None:
    """The held plan's target in the new capture's ids (else the new capture's last box)."""
    t = v.observed_of().get(plan.target) if plan.target else None
    return t or (scene.ids[-1] if scene.boxes else None)


def continuation(entry: PlanEntry, v: Verification, scene: Scene, held_session: int) -> PlanEntry | None:
    """The rest of the held plan in the new capture's ids; None when a box still to take was not seen.

    Its predicted shelves carry the held plan's simulated motions on from
    where the prediction stood after the held step, applied to the new
    capture's boxes, so the continued run is verified step by step too.
    """
    from shelfpick.planning.plan import StepPrediction
    from shelfpick.planning.predicted import predicted_shelves, sim_poses_after

    plan, k = entry.plan, v.step
    rest = plan.sequence[k + 1:]
    ids = v.observed_of()
    if not rest or any(b not in ids for b in rest):
        return None
    seq = tuple(ids[b] for b in rest)
    pred = tuple(StepPrediction(ids[p.box], p.collapse_prob, p.collision_prob,
                                tuple(ids[m] for m in p.moved if m in ids))
                 for p in plan.predicted[k + 1:] if p.box in ids)
    extra = {"continues": {"session": held_session, "plan": entry.hash, "after_step": k,
                           "deviation": v.summary()}}
    if plan.target is None:
        target = None
    else:
        target = ids[plan.target]
    cont = replace(plan, target=target, planner="continue", sequence=seq, predicted=pred,
                   timing={}, extra=extra)
    preview = tuple(renamed(r, ids) for r in entry.preview[k + 1:])
    start = renamed_poses(sim_poses_after(entry.preview, k), ids) if entry.preview else None
    shelves = tuple(predicted_shelves(scene, seq, preview, start)) if preview else ()
    return PlanEntry(cont, cont.content_hash(), preview, shelves)


def renamed_poses(poses: Mapping[str, Any], ids: Mapping[str, str]) -> dict[str, Any]:
    return {ids[b]: p for b, p in poses.items() if b in ids}


def renamed(step: PreviewStep, ids: Mapping[str, str]) -> dict[str, Any]:
    """A recorded preview step (object or JSON) with the box ids of another capture."""
    doc = step_json(step) if not isinstance(step, Mapping) else dict(step)
    doc["box"] = ids.get(doc.get("box"), doc.get("box"))
    for k in ("collapsed", "collided"):
        doc[k] = [ids[b] for b in doc.get(k, []) if b in ids]
    doc["frames"] = [[t, renamed_poses(poses, ids)] for t, poses in doc.get("frames", [])]
    return doc


__all__ = ["continuation", "mapped_target"]
