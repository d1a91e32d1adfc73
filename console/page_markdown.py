"""What the live page says, as markdown: the plans side by side, the robot, a deviation, the status line.

Pure functions of a workflow `State`; every piece of outside text (box ids,
robot messages, names) goes through `md()` so it shows literally.
"""
from __future__ import annotations

from collections.abc import Callable

from console.panels import md, pct
from console.workflow import PLANNERS, SECONDS_PER_BOX, PlanEntry, State, problem_text
from planning.plan import Plan


def results_markdown(state: State) -> str:
    """The two plans side by side."""
    if state.planning:
        return f"**Planning…** {md(state.progress_text)}"
    if not state.plans:
        return "_No plans yet. Select a target, then press `Plan extraction` or `Plan clearance`._"
    cols = [p for p in PLANNERS if p in state.plans]
    rows = ["| | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]

    def row(name: str, fn: Callable[[PlanEntry], str]) -> None:
        rows.append(f"| {name} | " + " | ".join(fn(state.plans[c]) for c in cols) + " |")

    row("sequence", lambda e: " → ".join(md(b) for b in e.plan.sequence) or "—")
    row("boxes removed", lambda e: str(len(e.plan.sequence)))
    row("collapse risk per step", lambda e: ", ".join(
        f"{md(p.box)} {pct(p.collapse_prob)}" for p in e.plan.predicted) or "—")
    row("max risk", lambda e: pct(e.plan.risk))
    row("predicted safe", lambda e: "yes" if e.plan.safe else "**NO**")
    row("sample worlds behind the risks", lambda e: _worlds(e.plan))
    row("scene check", lambda e: "; ".join(md(problem_text(p)) for p in e.scene_problems)
        if e.scene_problems else "stands as seen")
    row(f"est. execution ({SECONDS_PER_BOX:g} s/box)", lambda e: f"{e.est_seconds:.1f} s")
    row("planning time", lambda e: f"{_planning_seconds(e.plan):.2f} s")
    row("plan hash", lambda e: f"`{md(e.hash)}`")
    out = "\n".join(rows)
    if state.scene_problems:
        out += "\n\n**⚠ The shelf does not stand as seen** (no plan on it is safe):\n" + "\n".join(
            f"- {md(problem_text(p))}" for p in state.scene_problems)
    if state.repairs:
        out += "\n\n_Perceived scene adjusted by the physics:_ " + "; ".join(md(r) for r in state.repairs)
    return out


def _planning_seconds(plan: Plan) -> float:
    """Search time plus the depth-sample set-up it needed and the extra worlds a safe plan was
    asked of (all in the plan's timing)."""
    t = dict(plan.timing or {})
    return sum(float(t.get(k, 0.0)) for k in ("planning_s", "setup_s", "verify_s"))


def _worlds(plan: Plan) -> str:
    """How many sample worlds the plan's risks are over: the search's, or more for a plan found safe."""
    search = plan.extra.get("search", {}) if isinstance(plan.extra, dict) else {}
    n = search.get("verified_worlds") or search.get("worlds")
    return str(n) if isinstance(n, int) and not isinstance(n, bool) else "—"


def robot_markdown(state: State) -> str:
    lines = [f"**Robot:** {md(state.robot)}"]
    for ev in state.robot_events[-8:]:
        step = f" step {ev.step + 1}" if isinstance(ev.step, int) else ""
        note = ""
        if ev.kind in ("error", "disconnected", "aborted", "note") and ev.detail:
            note = ": " + md(ev.detail.get("message") or ev.detail.get("reason") or ev.detail.get("code") or "")
        lines.append(f"- {md(ev.kind)}{step}" + (f" {md(ev.box)}" if ev.box else "") + note)
    lines.extend(verification_lines(state))
    out = state.outcome
    if out is not None:
        lines.append(f"\n**Outcome:** {'success' if out.ok else 'not completed'}; "
                     f"completed: {', '.join(md(b) for b in out.completed) or 'none'}"
                     + (f"; error: {md(out.error)}" if out.error else ""))
    return "\n".join(lines)


def verification_lines(state: State) -> list[str]:
    """The look after each step of the current run: one line per verified step."""
    out = []
    for v in state.verifications:
        mark = "✓" if v.within else "⚠"
        out.append(f"- {mark} {md(v.summary())}")
    return out


def deviation_markdown(state: State) -> str:
    """Why the robot is held: each box predicted vs observed (ids are outside text: md())."""
    dev = state.deviation
    if dev is None:
        return ""
    v = dev.verification
    rows = [f"**⚠ Robot held before step {v.step + 2}:** {md(v.summary())}", "",
            "| predicted box | observed box | off by | turned | |", "|---|---|---|---|---|"]
    for d in v.boxes:
        if d.status == "ok":
            continue
        rows.append(f"| {md(d.predicted or '—')} | {md(d.observed or '—')} | {100 * d.displacement:.1f} cm "
                    f"| {d.rotation:.0f}° | {md(d.status)} |")
    rows.append(f"\n_Tolerance: {100 * v.tolerance.displacement:.0f} cm, {v.tolerance.rotation:.0f}°. "
                f"Red outlines: boxes that differ; blue outlines: where they were predicted. Plan again "
                f"from this capture (session {dev.session}), or a supervisor approves `continue` "
                f"(the rest of plan `{md(dev.plan)}` as planned, with 'Accept predicted risk')._")
    return "\n".join(rows)


def status_markdown(state: State, viewer: str = "") -> str:
    parts = []
    if state.audit:
        parts.append(f"**⛔ AUDIT: {md(state.audit)}**")
    for note in state.recovered:
        parts.append(f"**⚠ {md(note)}**")
    if state.error:
        parts.append(f"**⚠ {md(state.error)}**")
    if state.message:
        parts.append(md(state.message))
    head = f"Source {md(state.source)}"
    if state.session_id is not None:
        head += f" · session {state.session_id}"
    if state.target:
        head += f" · target **{md(state.target)}**"
    parts.append(head + (f" · {viewer}" if viewer else ""))
    for w in state.warnings[:3]:
        parts.append(f"_perception: {md(w)}_")
    return "\n\n".join(parts)


__all__ = ["results_markdown", "robot_markdown", "verification_lines", "deviation_markdown", "status_markdown"]
