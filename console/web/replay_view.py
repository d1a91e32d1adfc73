"""A stored session in the shape a browser's view draws it instead of the live state (the `Replay` button).

`record_view` turns a `SessionRecord` into a `ReplayView`: images, scene,
plans, the decisions and outcome as markdown, and one `LookView` per
verified step. Everything in it came from the database, so all of it is
outside text (md).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Mapping

from shelfpick.console.web.markdown import results_markdown
from shelfpick.console.web.panels import decisions_markdown, md
from shelfpick.console.web.replay import decided_planner, shown_worlds
from shelfpick.console.web.risk_text import pct
from shelfpick.console.web.segmentation_view import segmentation_image, set_aside_boxes
from shelfpick.console.web.time_words import start_time_words
from shelfpick.console.workflow.machine import PlanEntry, State
from shelfpick.perception.scene import Camera, Scene
from shelfpick.planning.plan import Plan

if TYPE_CHECKING:
    import numpy as np

    from shelfpick.console.store.sessions import SessionRecord


@dataclass(frozen=True, eq=False)
class ReplayPlan:
    """One planner's stored plan with its recorded preview (step JSON), as the preview player takes it."""

    plan: Plan
    preview: tuple[Mapping[str, Any], ...] | list[Mapping[str, Any]]
    hash: str
    shown: Mapping[int, Mapping[str, Any]] = field(default_factory=dict)   # step -> its collapse world


@dataclass(frozen=True, eq=False)
class LookView:
    """One stored look after a step: observed and predicted shelf, what differs, its table."""

    label: str
    step: int
    within: bool
    summary: str
    observed: Scene | None
    predicted: Scene | None
    md: str
    differ_o: tuple[str, ...]      # observed boxes that moved or are new (outlined red)


@dataclass(frozen=True, eq=False)
class ReplayView:
    """A stored session as a view draws it."""

    id: int
    rgb: np.ndarray | None
    overlay: np.ndarray | None
    scene: Scene
    camera: Camera | None
    target: str | None
    plans: Mapping[str, ReplayPlan]          # by planner; a later plan of a planner replaces an earlier one
    plans_md: str
    summary_md: str
    looks: tuple[LookView, ...]
    robot_md: str = ""                       # the robot's stored events and looks, as the live page shows a run


def record_view(rec: SessionRecord) -> ReplayView:
    """A stored `SessionRecord` in the shape a view draws: images, scene, plans, decisions, outcome."""
    plans: dict[str, ReplayPlan] = {}
    entries: dict[str, PlanEntry] = {}
    for pr in rec.plans:                       # later plans of a planner replace earlier ones
        plans[pr.plan.planner] = ReplayPlan(pr.plan, pr.preview or (), pr.hash, shown_worlds(pr.preview))
        entries[pr.plan.planner] = PlanEntry(pr.plan, pr.hash, ())
    problems = next((PlanEntry(pr.plan, pr.hash).scene_problems for pr in reversed(rec.plans)
                     if pr.plan.planner == "physics"), ())
    repairs = tuple(next((pr.plan.extra.get("repairs") or () for pr in reversed(rec.plans)
                          if pr.plan.planner == "physics"), ()))
    plans_md = results_markdown(State(plans=entries, scene_problems=problems, repairs=repairs)) \
        if entries else "_No plans in this session._"
    lines = [f"### Session {md(rec.id)}", f"started {md(start_time_words(rec.started))} · source {md(rec.source)} · "
             f"status **{md(rec.status)}** · {rec.n_boxes} boxes" + (f" · {md(rec.task)}" if rec.task else "")]
    if rec.missing_files:
        lines.append(f"**⚠ missing files:** {', '.join(md(f) for f in rec.missing_files)}")
    lines.append("\n**Decisions**")
    lines.append(decisions_markdown([{**d, "planner": decided_planner(d, rec)} for d in rec.decisions],
                                    key="plan_hash") or "- none")
    refused = [e for e in rec.robot_events if e["kind"] == "auth_refused"]
    if refused:
        lines.append(f"- {len(refused)} attempt(s) refused: wrong supervisor passphrase")
    stops = [e for e in rec.robot_events if e["kind"] == "stop"]
    for e in stops:
        lines.append(f"- “Stop robot” pressed by {md((e.get('detail') or {}).get('who'))} at {md(start_time_words(e['at']))}")
    out = rec.outcome
    if out:
        lines += _outcome_lines(out, plans, set(rec.scene.ids))
    else:
        lines.append("\n_The robot did not run in this session._")
    target = None
    for p in plans.values():
        target = p.plan.target or target
    cap = rec.capture
    looks = tuple(look_view(v) for v in rec.verifications)
    if looks:
        lines.append("\n**Looks after each step** (pick one in “Look after step”)")
        lines += [f"- {'✓' if lk.within else '⚠'} {md(lk.summary)}" for lk in looks]
    overlay = segmentation_image(cap.rgb if cap is not None else None, rec.overlay, rec.labels, rec.matter,
                                 rec.scene, set_aside_boxes([p.plan for p in plans.values()]))
    return ReplayView(id=rec.id, rgb=cap.rgb if cap is not None else None, overlay=overlay,
                      scene=rec.scene, camera=cap.camera if cap is not None else rec.scene.camera,
                      target=target, plans=plans, plans_md=plans_md, summary_md="\n".join(lines), looks=looks,
                      robot_md=stored_robot_markdown(rec))


class _StoredLook:
    """A stored verification in the shape `robot_markdown` reads (step, box, within, summary())."""

    def __init__(self, doc: Mapping[str, Any]) -> None:
        self.step = int(doc.get("step", 0))
        self.box = str(doc.get("box") or "")
        self.within = bool(doc.get("within"))
        self._summary = str((doc.get("verdict") or {}).get("summary", ""))

    def summary(self) -> str:
        return self._summary


def stored_robot_markdown(rec: SessionRecord) -> str:
    """The replayed session's robot: its events step by step with the looks, as the live page shows them."""
    from shelfpick.console.web.markdown import robot_markdown
    from shelfpick.console.robot.base import RobotEvent

    events = tuple(RobotEvent(e["kind"], e.get("step"), e.get("box"), e.get("detail") or {})
                   for e in rec.robot_events if e["kind"] not in ("auth_refused", "start", "stop", "sent"))
    state = State(robot=f"{rec.status} (replayed session {rec.id})", robot_events=events,
                  verifications=tuple(_StoredLook(v) for v in rec.verifications))   # type: ignore[arg-type]
    return robot_markdown(state) if events or rec.verifications else "_The robot did not run in this session._"


def replay_status(state: State, view: ReplayView) -> str:
    """The status line while a stored session is replayed: that session, not the live one (an audit
    failure of the live console stays on top of every view)."""
    head = (f"**Replaying session {view.id}** (stored: nothing here is live; press “Back to live” in "
            f"the Sessions tab to return)")
    if state.audit:
        return f"**⛔ AUDIT: {md(state.audit)}**\n\n{head}"
    return head


def look_view(v: Mapping[str, Any]) -> LookView:
    """One stored verification as the replay draws it: observed scene, predicted scene, what differs."""
    verdict = v.get("verdict") or {}
    diffs = [d for d in verdict.get("boxes", []) if d.get("status") != "ok"]
    rows = [f"**{'✓' if v.get('within') else '⚠'} {md(verdict.get('summary', ''))}**", ""]
    if diffs:
        rows += ["| predicted box | observed box | off by | turned | |", "|---|---|---|---|---|"]
        rows += [f"| {md(d.get('predicted') or '—')} | {md(d.get('observed') or '—')} | "
                 f"{100 * float(d.get('displacement_m', 0)):.1f} cm | {float(d.get('rotation_deg', 0)):.0f}° | "
                 f"{md(d.get('status'))} |" for d in diffs]
    rows.append("\n_Observed boxes drawn; blue outlines: the plan's predicted poses; red: boxes that differ._")
    return LookView(label=f"step {int(v['step']) + 1} ({v.get('box')}, plan {v.get('plan_hash')})",
                    step=int(v["step"]), within=bool(v.get("within")), summary=verdict.get("summary", ""),
                    observed=v.get("observed"), predicted=v.get("predicted"), md="\n".join(rows),
                    differ_o=tuple(d["observed"] for d in diffs if d.get("observed")
                                   and d.get("status") in ("moved", "new")))


def _outcome_lines(out: Mapping[str, Any], plans: Mapping[str, ReplayPlan], seen: set[str]) -> list[str]:
    head = ("success" if out.get("ok") else "interrupted (the console stopped)" if out.get("interrupted")
            else "stopped" if out.get("stopped") else "not completed")
    lines = ["\n**Robot outcome vs prediction**",
             f"{head} ({md(out.get('planner', '?'))} plan `{md(out.get('plan', ''))}`); completed: "
             f"{', '.join(md(b) for b in out.get('completed') or []) or 'none'}"
             + (f"; error: {md(out['error'])}" if out.get("error") else "")]
    pred = {}
    ran = plans.get(str(out.get("planner")))     # the plan that ran, by planner: two may share a hash
    for p in ([ran] if ran is not None and ran.hash == out.get("plan") else plans.values()):
        if p.hash == out.get("plan"):
            pred = {s.box: s for s in p.plan.predicted}
            break
    lines.append("\n| step | box | predicted collapse | actual |\n|---|---|---|---|")
    steps = out.get("steps") or []
    for i, box in enumerate(out.get("sequence") or []):
        st = steps[i] if i < len(steps) else None
        actual = _actual_text(st, seen) if st is not None else ("not run" if box not in (out.get("completed") or [])
                                                          else "done")
        p = pred.get(box)
        lines.append(f"| {i + 1} | {md(box)} | {pct(p.collapse_prob) if p else '—'} | {md(actual)} |")
    return lines


def _actual_text(step: Any, seen: set[str] | None = None) -> str:
    """A stored step of the outcome in words (a step that is not a JSON object is shown as it is).
    Collapsed boxes by the ids perception gave them (`seen`); one it never saw is said so."""
    if not isinstance(step, dict):
        return str(step)
    bits = []
    if step.get("status") in ("unknown", "error", "aborted", "not_sent", "skipped"):
        bits.append(str(step["status"]))
    if "extracted" in step:
        bits.append("extracted" if step["extracted"] else "NOT extracted")
    detail = step.get("detail") if isinstance(step.get("detail"), dict) else {}
    fell = step.get("collapsed") or detail.get("collapsed_ids") or []
    if fell:
        from shelfpick.console.robot.drivers import seen_names

        bits.append("collapsed: " + seen_names([str(b) if seen is None or str(b) in seen else None
                                                for b in fell]))
    if step.get("error"):
        bits.append(f"error: {step['error']}")
    return "; ".join(bits) or "done"


__all__ = ["ReplayView", "ReplayPlan", "LookView", "record_view", "look_view", "replay_status",
           "stored_robot_markdown"]
