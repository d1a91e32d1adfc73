"""What the live page says, as markdown: the plans side by side, the robot, a deviation, the status line.

Pure functions of a workflow `State`; every piece of outside text (box ids,
robot messages, names) goes through `md()` so it shows literally.
"""
from __future__ import annotations

from collections.abc import Callable

from shelfpick.console.web.panels import md, ours, touched
from shelfpick.console.web.risk_text import pct, plan_risk
from shelfpick.console.workflow.machine import PLANNERS, SECONDS_PER_BOX, PlanEntry, State, problem_text
from shelfpick.planning.plan import Plan


NBSP = "\u00a0"
SHOWN = (*PLANNERS, "continue")        # the plans a page shows side by side, in this order


def results_markdown(state: State) -> str:
    """The plans side by side (the physics and heuristic plans, or the held plan's `continue`)."""
    if state.planning:
        return f"**Planning…** {md(state.progress_text)}"
    if state.capturing:
        return "**Capturing…** The plan buttons work once the capture is in."
    if not state.plans:
        return "_No plans yet. Select a target, then press **Plan extraction** or **Plan clearance**._"
    cols = [p for p in SHOWN if p in state.plans]
    rows = ["| | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]

    def row(name: str, fn: Callable[[PlanEntry], str]) -> None:
        rows.append(f"| {name} | " + " | ".join(fn(state.plans[c]) for c in cols) + " |")

    row("sequence", lambda e: " → ".join(md(b) for b in e.plan.sequence) or "—")
    row("boxes removed", lambda e: str(len(e.plan.sequence)))
    # one step a line, box and risk kept together: a long sequence never wraps inside an item
    row("collapse risk per step", lambda e: "<br>".join(
        f"{i + 1}.{NBSP}{md(p.box)}{NBSP}{pct(p.collapse_prob)}" + _collision(p)
        for i, p in enumerate(e.plan.predicted)) or "—")
    # a plan's risk is its riskiest step's collapse OR collision chance: say so, and show the collisions
    # per step above, or a plan of 0% steps reads "max risk 50%" with nothing to explain it
    row("max risk (collapse or collision)", lambda e: pct(e.plan.risk))
    row("predicted safe", lambda e: "yes" if e.plan.safe else "**NO**")
    row("chance of a collapse (calibrated)", lambda e: _plan_risk(e.plan))
    row("sample worlds behind the risks", lambda e: _worlds(e.plan))
    row("scene check", lambda e: "; ".join(md(problem_text(p)) for p in e.scene_problems)
        if e.scene_problems else "stands as seen")
    if any(touched(state.plans[c].plan) is not None for c in cols):    # issue 31: matter no box explains
        row("unexplained matter", lambda e: "<br>".join(md(t) for t in touched(e.plan) or ()) or "not touched")
    if any(touched(state.plans[c].plan, "contradicted") is not None for c in cols):   # faces perception doubts
        row("faces that cannot all be right", lambda e: "<br>".join(
            md(t) for t in touched(e.plan, "contradicted") or ()) or "not touched")
    if any(state.plans[c].plan.extra.get("set_aside") for c in cols):    # faces no world can hold
        row("faces set aside as unexplained matter", lambda e: "<br>".join(
            md(f"{' and '.join(map(str, a.get('boxes', ())))}: {a.get('why', '')}")
            for a in e.plan.extra.get("set_aside") or ()) or "none")
    row(f"est. execution ({SECONDS_PER_BOX:g}{NBSP}s/box)", lambda e: f"{e.est_seconds:.1f}{NBSP}s")
    row("planning time", lambda e: f"{_planning_seconds(e.plan):.2f}{NBSP}s"
        if e.plan.planner != "continue" else "—")
    row("plan hash", lambda e: f"`{md(e.hash)}`")
    out = "\n".join(rows)
    out += ("\n\n_Risks are counted over sample worlds: shelves the camera cannot tell apart (box "
            "depths, masses, friction). A plan whose risk is too near the threshold to call it safe "
            "or not is asked of more worlds before the gate decides._")
    if state.scene_problems:
        out += "\n\n**⚠ The shelf does not stand as seen** (no plan on it is safe):\n" + "\n".join(
            f"- {md(problem_text(p))}" for p in state.scene_problems)
    if state.repairs:
        out += "\n\n_Perceived scene adjusted by the physics:_ " + "; ".join(md(r) for r in state.repairs)
    return out


def _collision(p) -> str:
    """A step's collision chance beside its collapse chance, where it has one."""
    return f",{NBSP}collision{NBSP}{pct(p.collision_prob)}" if p.collision_prob > 0 else ""


def _planning_seconds(plan: Plan) -> float:
    """What the operator waited for this plan: the console's wall time for it (search, risks and
    preview; `wall_s`) when known, else the planner's search time, plus the depth-sample set-up and
    the extra worlds a safe plan was asked of."""
    t = dict(plan.timing or {})
    own = float(t["wall_s"]) if "wall_s" in t else float(t.get("planning_s", 0.0)) + float(t.get("verify_s", 0.0))
    return own + float(t.get("setup_s", 0.0))


def _plan_risk(plan: Plan) -> str:
    """The plan's calibrated chance of a collapse, its interval and the cell's threshold (issue 32):
    the plan is safe when the interval's upper end is below the threshold. Then the evidence behind
    it, the gate's worlds in which some step failed: the map can call a plan safe that collapsed in
    a few of them (it is fitted on a gripper that lifts), and the supervisor should see that."""
    risk = plan_risk(plan)
    if risk is None:
        return "—"
    g, p, hi, limit = risk
    text = f"{100 * p:.1f}% (up to {100 * hi:.1f}%; threshold {100 * limit:.1f}%)"
    k, n = g.get("failed_worlds"), g.get("worlds")
    if all(isinstance(x, int) and not isinstance(x, bool) for x in (k, n)) and 0 <= k <= n and n > 0:
        text += f"; failed in {k} of {n} sample worlds"
    return text


def _worlds(plan: Plan) -> str:
    """How many sample worlds the plan's risks are over, and why the gate asked more. A gated plan's
    risks are over the gate's own worlds, asked after the ones the search chose the plan in (the
    baseline chooses in none: its steps were first predicted there)."""
    search = plan.extra.get("search", {}) if isinstance(plan.extra, dict) else {}
    n, v = search.get("worlds"), search.get("verified_worlds")
    if not (isinstance(n, int) and not isinstance(n, bool)):
        return "—"
    counted = isinstance(v, int) and not isinstance(v, bool)
    if counted and isinstance(search.get("plan_risk"), dict):
        first = "the search chose the plan in" if plan.planner == "physics" else "its steps were first predicted in"
        return f"{v} (fresh: asked after the {n} {first})"
    if counted and v > n:
        return f"{v} ({n} searched; {v - n} more asked to decide whether it is safe)"
    return f"{n} (searched)"


def robot_markdown(state: State) -> str:
    """The run so far: one row per step (the robot's events, then the look after it), in step order,
    every step of the plan; what belongs to no step (notes, stop) below it."""
    lines = [f"**Robot:** {md(state.robot)}"]
    steps: dict[int, dict] = {}
    other: list[str] = []
    for ev in state.robot_events:
        note = ""
        if ev.kind in ("error", "disconnected", "aborted", "note") and ev.detail:
            note = ": " + md(ev.detail.get("message") or ev.detail.get("reason") or ev.detail.get("code") or "")
        if isinstance(ev.step, int):
            row = steps.setdefault(ev.step, {"box": ev.box, "robot": [], "look": ""})
            row["robot"].append(md(ev.kind) + note)
        else:
            other.append(f"- {md(ev.kind)}" + (f" {md(ev.box)}" if ev.box else "") + note)
    for v in state.verifications:
        row = steps.setdefault(v.step, {"box": v.box, "robot": [], "look": ""})
        text = v.summary()
        head = f"step {v.step + 1} ({v.box}): "
        row["look"] = f"{'✓' if v.within else '⚠'} {md(text[len(head):] if text.startswith(head) else text)}"
    if steps:
        lines += ["", "| step | box | robot | look after it |", "|---|---|---|---|"]
        for k in sorted(steps):
            r = steps[k]
            lines.append(f"| {k + 1} | {md(r['box'] or '')} | {' → '.join(r['robot']) or '—'} | {r['look'] or '—'} |")
        lines.append("")
    lines += other
    out = state.outcome
    if out is not None:
        lines.append(f"\n**Outcome:** {'success' if out.ok else 'not completed'}; "
                     f"completed: {', '.join(md(b) for b in out.completed) or 'none'}"
                     + (f"; error: {ours(out.error)}" if out.error else ""))
    return "\n".join(lines)


def verification_lines(state: State) -> list[str]:
    """The look after each step of the current run: one line per verified step."""
    out = []
    for v in state.verifications:
        mark = "✓" if v.within else "⚠"
        out.append(f"- {mark} {md(v.summary())}")
    return out


def deviation_markdown(state: State) -> str:
    """Why the robot is held: each box predicted vs observed (ids are outside text: md()).

    Shown while the robot stands held (`robot == "held"`); once a run starts from
    the held capture (continue, or a new plan) the notice is history: the replay keeps it."""
    dev = state.deviation
    if dev is None or state.robot != "held":
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
        parts.append(f"**⛔ AUDIT: {ours(state.audit)}**")
    for note in state.recovered:
        parts.append(f"**⚠ {ours(note)}**")
    if state.error:
        parts.append(f"**⚠ {ours(state.error)}**")
    if state.message:
        parts.append(ours(state.message))
    head = f"Source {md(state.source)}"
    if state.session_id is not None:
        head += f" · session {state.session_id}"
    if state.target:
        head += f" · target **{md(state.target)}**"
    parts.append(head + (f" · {viewer}" if viewer else ""))
    for w in state.warnings:        # every one: a "cannot all be right" marks boxes the plans avoid calling safe
        parts.append(f"_perception: {md(w)}_")
    return "\n\n".join(parts)


__all__ = ["ours", "results_markdown", "robot_markdown", "verification_lines", "deviation_markdown", "status_markdown"]
