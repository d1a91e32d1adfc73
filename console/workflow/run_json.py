"""The JSON the workflow stores: a perception's summary, a preview step, a run's outcome."""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from shelfpick.console.workflow.state import PlanEntry

if TYPE_CHECKING:
    from shelfpick.console.robot.base import RobotOutcome
    from shelfpick.console.workflow.state import PreviewStep
    from shelfpick.perception.pipeline import Perception


def perception_summary(perception: Perception) -> dict:
    try:
        return dict(perception.summary())
    except Exception:  # noqa: BLE001 - an older Perception without summary()
        return {"warnings": list(perception.warnings), "timing": dict(perception.timing)}


def step_json(result: PreviewStep) -> dict:
    """A preview step with its recorded frames, so a replay can animate it without the server."""
    try:
        return result.to_json(frames=True)
    except TypeError:
        return result.to_json()


def outcome_json(outcome: RobotOutcome | None, err: str | None, entry: PlanEntry, stopped: bool,
                  stopped_by: str | None = None) -> dict:
    doc: dict[str, Any] = {"plan": entry.hash, "planner": entry.plan.planner,
                           "sequence": list(entry.plan.sequence), "stopped": stopped}
    if stopped_by:
        doc["stopped_by"] = stopped_by
    if outcome is not None:
        doc.update({"completed": list(outcome.completed), "ok": bool(outcome.ok), "error": outcome.error or err,
                    "steps": [dict(s) for s in outcome.steps]})
    else:
        doc.update({"completed": [], "ok": False, "error": err, "steps": []})
    return doc


__all__ = ["perception_summary", "step_json", "outcome_json"]
