"""What each step of a run did, read from the stored robot events and looks (pure functions of rows).

`step_states` is "never re-send a step": a step acknowledged by the robot
and never reported finished stays `in_flight`, and `unknown` when the link or
the console died with it, whatever happens after. A step whose `sent` record
(committed before the step goes out) has nothing after it is `sent`: a run
that ended normally had it unacknowledged (the robot must not move before
its `ack`), but when the console died with it, its `ack` may have come and
not been committed, so the restart calls it unknown, never `not_sent`. `interrupted_run` is the
record a restarted console writes for a run whose console died mid-run.
`verification_stats` and `step_stats` pair what the plan predicted for each
step with what the robot and the look after the step reported.
"""
from __future__ import annotations

import json
import sqlite3
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

StepStates = dict[int, tuple[str, str | None]]

INTERRUPTED_REASON = ("the console stopped (crash or kill) while this step was in flight; "
                      "its outcome is unknown")
SENT_REASON = ("the console stopped (crash, kill, or closed with records it could not commit) after this "
               "step was sent; its acknowledgement is not on record, so its outcome is unknown: look at the shelf")


def step_states(rows: Iterable[sqlite3.Row]) -> StepStates:
    """step -> (state, box) from robot events (kind, step, box, detail) in the order they happened."""
    out: StepStates = {}
    for r in rows:
        kind, step = r["kind"], int(r["step"])
        prev = out.get(step, ("", None))[0]
        if kind == "sent":
            state = "sent" if prev in ("", "sent", "failed", "aborted") else prev
        elif kind == "ack":
            state = "in_flight"
        elif kind == "done":
            state = "done"
        elif kind == "error":
            state = "failed" if prev != "done" else "done"
        elif kind == "aborted":
            unconfirmed = "unconfirmed" in (json.loads(r["detail"]) if r["detail"] else {})
            state = "unknown" if unconfirmed and prev != "done" else (prev if prev == "done" else "aborted")
        elif kind in ("disconnected", "unknown"):
            state = "unknown" if prev != "done" else "done"
        else:
            continue
        out[step] = (state, r["box"])
    return out


OPEN_STATES = ("in_flight", "sent")   # what a dead console's run leaves with an unknown outcome


@dataclass(frozen=True)
class InterruptedRun:
    """A dead console's run as the restart records it."""

    outcome: dict                             # the session's outcome: interrupted, not ok
    unknown: list[tuple[int, str | None]]     # (step, box) sent or in flight when it died: an `unknown` each
    completed: list[str]                      # boxes whose step the robot reported done


def interrupted_run(plan_hash: str, sequence: list,
                    states: Mapping[int, tuple[str, str | None]]) -> InterruptedRun:
    """The outcome of a run whose console died: steps sent or in flight are unknown, the rest as reported."""
    unknown = [(i, box) for i, (st, box) in sorted(states.items()) if st in OPEN_STATES]
    steps = []
    for i, box in enumerate(sequence):
        st = states.get(i, ("not_sent", box))[0]
        reason = {"in_flight": INTERRUPTED_REASON, "sent": SENT_REASON}.get(st)
        steps.append({"step": i, "box": box, "status": "unknown" if reason else st,
                      "detail": {"reason": reason} if reason else {}})
    done = [box for i, box in enumerate(sequence) if states.get(i, ("",))[0] == "done"]
    err = "the console stopped during execution (crash or kill)" + (
        "; step " + ", ".join(f"{i + 1} ({b})" for i, b in unknown) + ": outcome unknown" if unknown else "")
    outcome = {"plan": plan_hash, "sequence": sequence, "completed": done, "ok": False, "stopped": False,
               "interrupted": True, "error": err, "steps": steps}
    return InterruptedRun(outcome, unknown, done)


def _predicted(plan_text: str | None, step: int) -> tuple[dict, dict]:
    """The stored plan (JSON) and its prediction for `step` ({} when it has none)."""
    plan = json.loads(plan_text) if plan_text else {}
    pred = plan.get("predicted") or []
    return plan, pred[step] if step < len(pred) and isinstance(pred[step], dict) else {}


def verification_stats(rows: Iterable[sqlite3.Row]) -> list[dict]:
    """Per verified step (rows: session_id, plan_hash, step, box, within, verdict, plan): plan hash,
    step, within, and the plan's predicted risk."""
    out = []
    for r in rows:
        step = int(r["step"])
        plan, p = _predicted(r["plan"], step)
        out.append({"session": r["session_id"], "plan": r["plan_hash"], "planner": plan.get("planner"),
                    "step": step, "box": r["box"], "within": bool(r["within"]),
                    "collapse_prob": float(p.get("collapse_prob", 0.0) or 0.0),
                    "collision_prob": float(p.get("collision_prob", 0.0) or 0.0),
                    "verdict": json.loads(r["verdict"])})
    return out


def step_stats(rows: Iterable[sqlite3.Row], verified: list[dict]) -> list[dict]:
    """Per step a robot reported done (rows: done/error events with their plan): the predicted risk,
    whether the robot reported boxes collapsing, and the look after it (None: not verified)."""
    looks = {(v["session"], v["plan"], v["step"]): v for v in verified}
    out: dict[tuple, dict] = {}
    for r in rows:
        key = (r["session_id"], r["plan_hash"], int(r["step"]))
        detail = json.loads(r["detail"]) if r["detail"] else {}
        collapsed = bool(detail.get("collapsed")) or detail.get("code") == "COLLAPSE"
        if r["kind"] == "error":
            if key in out and collapsed:
                out[key]["robot_collapse"] = True
            continue
        plan, p = _predicted(r["plan"], key[2])
        look = looks.get(key)
        verdict = look["verdict"] if look else None
        out[key] = {"session": key[0], "plan": key[1], "planner": plan.get("planner"), "step": key[2],
                    "box": r["box"], "collapse_prob": float(p.get("collapse_prob", 0.0) or 0.0),
                    "robot_collapse": collapsed,
                    "verified": None if look is None else (
                        "unavailable" if verdict.get("unavailable") else
                        "within" if look["within"] else "deviation")}
    return list(out.values())
