"""The operator console: a viser web app over `console.workflow.Workflow`.

Thin on purpose: every rule (which plan may run, who may approve) lives in
the workflow; this module draws its state. Each browser gets its own view
(GUI and 3D scene through `client.gui` / `client.scene`) so that a
supervisor's passphrase never travels to another browser and one person
scrubbing a preview does not move everybody's boxes, while the workflow
state they all draw is one and the same: every change is pushed to every
connected view at once.
"""
from __future__ import annotations

import threading
import traceback
from typing import Any, Mapping

from console.panels import (OperatorPanel, PreviewPlayer, SessionsPanel, ShelfDrawing, SupervisorPanel,
                            decisions_markdown, md, pct)
from console.workflow import PLANNERS, SECONDS_PER_BOX, State, Workflow, WorkflowError, problem_text
from perception.errors import ShelfpickError

LOCAL_HOSTS = {"127.0.0.1", "localhost", "::1"}
MIN_PASSPHRASE = 12          # characters, when the console listens beyond this machine


class ConsoleError(ShelfpickError):
    """A console start-up setting the user must change."""


def check_host(host: str, passphrase: str | None) -> None:
    """Listening beyond this machine requires a supervisor passphrase chosen by a person,
    at least MIN_PASSPHRASE characters that are not all blank."""
    if host in LOCAL_HOSTS:
        return
    if not passphrase:
        raise ConsoleError(f"--host {host}: listening on a non-local address needs a supervisor "
                           "passphrase (--supervisor-passphrase or SHELFPICK_SUPERVISOR_PASSPHRASE)")
    if len(passphrase.strip()) < MIN_PASSPHRASE:
        raise ConsoleError(f"--supervisor-passphrase: at least {MIN_PASSPHRASE} characters (not counting "
                           f"blanks at the ends) when listening on {host}, got {len(passphrase.strip())}")


def results_markdown(state: State) -> str:
    """The two plans side by side."""
    if state.planning:
        return f"**Planning…** {md(state.progress_text)}"
    if not state.plans:
        return "_No plans yet. Select a target, then press `Plan extraction` or `Plan clearance`._"
    cols = [p for p in PLANNERS if p in state.plans]
    rows = ["| | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]

    def row(name: str, fn) -> None:
        rows.append(f"| {name} | " + " | ".join(fn(state.plans[c]) for c in cols) + " |")

    row("sequence", lambda e: " → ".join(md(b) for b in e.plan.sequence) or "—")
    row("boxes removed", lambda e: str(len(e.plan.sequence)))
    row("collapse risk per step", lambda e: ", ".join(
        f"{md(p.box)} {pct(p.collapse_prob)}" for p in e.plan.predicted) or "—")
    row("max risk", lambda e: pct(e.plan.risk))
    row("predicted safe", lambda e: "yes" if e.plan.safe else "**NO**")
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


def _planning_seconds(plan: Any) -> float:
    """Search time plus the depth-sample set-up it needed (both in the plan's timing)."""
    t = dict(plan.timing or {})
    return float(t.get("planning_s", 0.0)) + float(t.get("setup_s", 0.0))


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


class _InPanel:
    """A view attribute that lives in one of its panels (what tests and scripts reach through the view)."""

    def __init__(self, panel: str) -> None:
        self.panel = panel
        self.name = ""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    def __get__(self, view: Any, owner: type) -> Any:
        if view is None:
            return self
        return getattr(getattr(view, self.panel), self.name)


class ClientView:
    """Everything one browser sees: its panels, rebuilt from the workflow state on every change.

    The view holds what crosses panels: the replay record (a stored session drawn instead of the
    live state), which scene, capture and plans are drawn, and the lock every panel draws under."""

    status, robot_md, deviation_md, target = (_InPanel("operator") for _ in range(4))
    slider = _InPanel("preview")
    who, passphrase, approve_plan, accept_risk, reason, decisions_md = (_InPanel("supervisor") for _ in range(6))
    session_pick, look_pick, replay_md, look_md, look_nodes = (_InPanel("sessions") for _ in range(5))
    nodes, predicted_nodes = _InPanel("drawing"), _InPanel("drawing")

    def __init__(self, app: "ConsoleApp", client: Any) -> None:
        self.app = app
        self.client = client
        self.wf: Workflow = app.workflow
        self.lock = threading.RLock()
        self.shown_scene: Any = None
        self.shown_capture: Any = None
        self.shown_plans: Any = None
        self.replay: Any = None
        self.client_key = f"browser-{getattr(client, 'client_id', id(client))}"   # for the throttle
        self.drawing = drawing = ShelfDrawing(client)
        g = client.gui
        tabs = g.add_tab_group()
        with tabs.add_tab("Operator"):
            self.operator = OperatorPanel(g, self.wf, self._do, lambda gui: PreviewPlayer(
                gui, self.lock, drawing, self._preview_source, self._scene, self._highlight))
        self.preview = self.operator.preview
        with tabs.add_tab("Supervisor"):
            self.supervisor = SupervisorPanel(g, self.wf, self._do, lambda: self.client_key)
        with tabs.add_tab("Sessions"):
            self.sessions = SessionsPanel(g, self.wf)
        self.sessions.btn_replay.on_click(self._replay)
        self.sessions.btn_live.on_click(self._live)
        self.sessions.look_pick.on_update(lambda e: self._show_look(self.sessions.look_pick.value))
        client.scene.set_up_direction("+z")

    # --------------------------------------------------------------- actions
    def notify(self, title: str, body: str, color: str = "red") -> None:
        try:
            self.client.add_notification(title, body, color=color, auto_close_seconds=8.0)
        except Exception:  # noqa: BLE001 - a closed browser
            pass

    def _do(self, event: Any, fn: Any, *args: Any) -> None:
        try:
            fn(*args)
        except (WorkflowError, ShelfpickError) as exc:
            self.notify("Not done", str(exc))
        except Exception as exc:  # noqa: BLE001 - the server keeps running
            traceback.print_exc()
            self.notify("Error", f"{exc.__class__.__name__}: {exc}")

    def _approve(self, event: Any) -> None:
        self.supervisor.approve(event)

    def _reject(self, event: Any) -> None:
        self.supervisor.reject(event)

    def _click_box(self, box_id: str) -> None:
        if self.replay is not None:
            return
        try:
            self.wf.select_target(box_id)
        except (WorkflowError, ShelfpickError) as exc:
            self.notify("Not done", str(exc))

    def stop_preview(self) -> None:
        """The preview thread ends at its next frame (the browser went away or the server stops)."""
        self.preview.playing = False

    # ---------------------------------------------------------------- render
    def _preview_source(self, name: str) -> tuple[Any, Any]:
        """(preview step results, plan) for the chosen planner, live or replayed."""
        if self.replay is not None:
            plans = self.replay.get("plans", {})
            e = plans.get(name)
            return (e["preview"], e["plan"]) if e else ((), None)
        e = self.wf.state.plans.get(name)
        return (e.preview, e.plan) if e else ((), None)

    def _scene(self) -> Any:
        if self.replay is not None:
            return self.replay.get("scene")
        return self.wf.state.scene

    def _draw_scene(self, scene: Any, camera: Any) -> None:
        self.drawing.draw(scene, camera, self.shown_scene is None, self._click_box)

    def _highlight(self) -> None:
        target = self.replay.get("target") if self.replay is not None else self.wf.state.target
        risk = set(self.preview.risk)
        dev = self.wf.state.deviation if self.replay is None else None
        look = self.replay.get("shown_look") if self.replay is not None else None
        if look is not None:
            risk = set(look["differ_o"])
        if dev is not None and self.wf.state.session_id == dev.session:
            risk |= {d.observed for d in dev.verification.boxes if d.status in ("moved", "new")}
        self.drawing.mark(target, risk, dev)

    def render(self, state: State) -> None:
        with self.lock:
            try:
                self._render(state)
            except Exception:  # noqa: BLE001 - a client that went away mid-update
                traceback.print_exc()

    def _render(self, state: State) -> None:
        live = self.replay is None
        op = self.operator
        op.status.content = status_markdown(state, "" if live else f"**replaying session "
                                            f"{self.replay.get('id')}** (press `Back to live`)")
        op.progress.visible = state.planning
        op.progress.value = 100.0 * state.progress
        for b in (op.btn_extract, op.btn_clear):
            b.disabled = state.planning
        op.robot_md.content = robot_markdown(state)
        op.deviation_md.content = deviation_markdown(state) if self.replay is None else ""
        self.supervisor.render(state)
        self.sessions.render(state)
        if not live:
            return
        op.results.content = results_markdown(state)
        if state.capture is not self.shown_capture:
            self.shown_capture = state.capture
            op.show_images(state.capture.rgb if state.capture is not None else None, state.overlay)
        if state.scene is not self.shown_scene:
            self._draw_scene(state.scene, state.capture.camera if state.capture is not None else None)
            self.shown_scene = state.scene
            self.shown_plans = None
            op.show_targets(state.scene)
        op.follow_target(state.target)
        if state.plans is not self.shown_plans:
            self.shown_plans = state.plans
            self.preview.load()
        self._highlight()

    # ---------------------------------------------------------------- replay
    def _replay(self, event: Any) -> None:
        v = self.sessions.session_pick.value
        if v == "—":
            self.notify("Not done", "no session to replay")
            return
        try:
            rec = self.app.load_replay(int(v))
        except Exception as exc:  # noqa: BLE001
            traceback.print_exc()
            self.notify("Replay failed", str(exc))
            return
        with self.lock:
            self.replay = rec
            self.operator.show_images(rec.get("rgb"), rec.get("overlay"))
            self._draw_scene(rec.get("scene"), rec.get("camera"))
            self.shown_scene = None
            self.shown_capture = None
            self.shown_plans = None
            self.operator.results.content = rec["plans_md"]
            self.sessions.start_replay(rec)
            self.preview.load()
            self.render(self.wf.state)

    def _show_look(self, label: str) -> None:
        """Replay: the shelf observed after one step with the plan's predicted poses as outlines."""
        with self.lock:
            if self.replay is None:
                return
            self.sessions.clear_look()
            look = next((lk for lk in self.replay.get("looks", ()) if lk["label"] == label), None)
            self.replay["shown_look"] = look
            if look is None or look["observed"] is None:
                self._draw_scene(self.replay.get("scene"), self.replay.get("camera"))
            else:
                self._draw_scene(look["observed"], self.replay.get("camera"))
                self.sessions.show_look(self.client.scene, look)
            self._highlight()

    def _live(self, event: Any) -> None:
        with self.lock:
            self.replay = None
            self.sessions.end_replay()
            self.shown_scene = None       # draw the live shelf again
            self.render(self.wf.state)


def record_view(rec: Any) -> dict:
    """A stored `SessionRecord` in the shape a view draws: images, scene, plans, decisions, outcome.

    Everything in it came from the database, so all of it is outside text (md)."""
    from console.workflow import PlanEntry, State

    plans: dict[str, dict] = {}
    entries: dict[str, PlanEntry] = {}
    for pr in rec.plans:                       # later plans of a planner replace earlier ones
        plans[pr.plan.planner] = {"plan": pr.plan, "preview": pr.preview or (), "hash": pr.hash}
        entries[pr.plan.planner] = PlanEntry(pr.plan, pr.hash, ())
    problems = next((PlanEntry(pr.plan, pr.hash).scene_problems for pr in reversed(rec.plans)
                     if pr.plan.planner == "physics"), ())
    repairs = tuple(next((pr.plan.extra.get("repairs") or () for pr in reversed(rec.plans)
                          if pr.plan.planner == "physics"), ()))
    plans_md = results_markdown(State(plans=entries, scene_problems=problems, repairs=repairs)) \
        if entries else "_No plans in this session._"
    lines = [f"### Session {md(rec.id)}", f"started {md(rec.started)} · source {md(rec.source)} · "
             f"status **{md(rec.status)}** · {rec.n_boxes} boxes" + (f" · {md(rec.task)}" if rec.task else "")]
    if rec.missing_files:
        lines.append(f"**⚠ missing files:** {', '.join(md(f) for f in rec.missing_files)}")
    lines.append("\n**Decisions**")
    lines.append(decisions_markdown(rec.decisions, key="plan_hash") or "- none")
    refused = [e for e in rec.robot_events if e["kind"] == "auth_refused"]
    if refused:
        lines.append(f"- {len(refused)} attempt(s) refused: wrong supervisor passphrase")
    stops = [e for e in rec.robot_events if e["kind"] == "stop"]
    for e in stops:
        lines.append(f"- `Stop robot` pressed by {md((e.get('detail') or {}).get('who'))} at {md(e['at'])}")
    out = rec.outcome
    if out:
        lines += _outcome_lines(out, plans)
    else:
        lines.append("\n_The robot did not run in this session._")
    target = None
    for p in plans.values():
        target = p["plan"].target or target
    cap = rec.capture
    looks = [look_view(v) for v in rec.verifications]
    if looks:
        lines.append("\n**Looks after each step** (pick one in `Look after step`)")
        lines += [f"- {'✓' if lk['within'] else '⚠'} {md(lk['summary'])}" for lk in looks]
    return {"id": rec.id, "rgb": cap.rgb if cap is not None else None, "overlay": rec.overlay,
            "scene": rec.scene, "camera": cap.camera if cap is not None else rec.scene.camera,
            "target": target, "plans": plans, "plans_md": plans_md, "summary_md": "\n".join(lines),
            "looks": looks}


def look_view(v: Mapping[str, Any]) -> dict:
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
    return {"label": f"step {int(v['step']) + 1} ({v.get('box')}, plan {v.get('plan_hash')})",
            "step": int(v["step"]), "within": bool(v.get("within")), "summary": verdict.get("summary", ""),
            "observed": v.get("observed"), "predicted": v.get("predicted"), "md": "\n".join(rows),
            "differ_o": tuple(d["observed"] for d in diffs if d.get("observed")
                              and d.get("status") in ("moved", "new"))}


def _outcome_lines(out: dict, plans: dict) -> list[str]:
    head = ("success" if out.get("ok") else "interrupted (the console stopped)" if out.get("interrupted")
            else "stopped" if out.get("stopped") else "not completed")
    lines = ["\n**Robot outcome vs prediction**",
             f"{head} ({md(out.get('planner', '?'))} plan `{md(out.get('plan', ''))}`); completed: "
             f"{', '.join(md(b) for b in out.get('completed') or []) or 'none'}"
             + (f"; error: {md(out['error'])}" if out.get("error") else "")]
    pred = {}
    for p in plans.values():
        if p["hash"] == out.get("plan"):
            pred = {s.box: s for s in p["plan"].predicted}
    lines.append("\n| step | box | predicted collapse | actual |\n|---|---|---|---|")
    steps = out.get("steps") or []
    for i, box in enumerate(out.get("sequence") or []):
        st = steps[i] if i < len(steps) else None
        actual = _actual_text(st) if st is not None else ("not run" if box not in (out.get("completed") or [])
                                                          else "done")
        p = pred.get(box)
        lines.append(f"| {i + 1} | {md(box)} | {pct(p.collapse_prob) if p else '—'} | {md(actual)} |")
    return lines


def _actual_text(step: Any) -> str:
    if not isinstance(step, dict):
        return str(step)
    bits = []
    if step.get("status") in ("unknown", "error", "aborted", "not_sent", "skipped"):
        bits.append(str(step["status"]))
    if "extracted" in step:
        bits.append("extracted" if step["extracted"] else "NOT extracted")
    if step.get("collapsed"):
        bits.append("collapsed: " + ", ".join(map(str, step["collapsed"])))
    if step.get("error"):
        bits.append(f"error: {step['error']}")
    return "; ".join(bits) or "done"


class ConsoleApp:
    """The viser server, one `ClientView` per browser, all fed by one workflow."""

    def __init__(self, workflow: Workflow, host: str = "127.0.0.1", port: int = 8080,
                 passphrase_set: bool = True, verbose: bool = False) -> None:
        # passphrase_set: a person chose the workflow's passphrase (a generated one is for localhost)
        check_host(host, workflow._passphrase if passphrase_set else None)
        import viser

        self.workflow = workflow
        self.server = viser.ViserServer(host=host, port=port, verbose=verbose)
        self.host = host
        self.server.gui.configure_theme(control_width="large",
                                        show_share_button=False, dark_mode=False)
        self.server.gui.main_panel.dock_right()
        self.server.scene.set_up_direction("+z")
        # shadows cost a lot in software WebGL (browsers without a GPU) and add nothing here
        self.server.scene.configure_default_lights(True, cast_shadow=False)
        # no HDRI environment: building it takes ~15 s in software WebGL at the first mesh
        self.server.scene.configure_environment_map(None)
        self.server.scene.add_light_ambient("/lights/ambient", intensity=1.2)
        # three.js directional lights shine from their position towards the origin: from the front
        self.server.scene.add_light_directional("/lights/front", intensity=1.5, cast_shadow=False,
                                                position=(0.6, -2.0, 1.6))
        cam = self.server.initial_camera
        cam.position = (0.7, -2.0, 1.1)
        cam.look_at = (0.0, 0.15, 0.55)
        cam.up = (0.0, 0.0, 1.0)
        self.views: dict[int, ClientView] = {}
        self._views_lock = threading.Lock()
        self.server.on_client_connect(self._connect)
        self.server.on_client_disconnect(self._disconnect)
        workflow.add_listener(self._on_state)

    @property
    def port(self) -> int:
        return self.server.get_port()

    @property
    def url(self) -> str:
        host = "127.0.0.1" if self.host in ("0.0.0.0", "::") else self.host
        return f"http://{host}:{self.port}"

    def _connect(self, client: Any) -> None:
        view = ClientView(self, client)
        with self._views_lock:
            self.views[client.client_id] = view
        view.render(self.workflow.state)

    def _disconnect(self, client: Any) -> None:
        with self._views_lock:
            view = self.views.pop(client.client_id, None)
        if view is not None:
            view.stop_preview()

    def _on_state(self, state: State) -> None:
        with self._views_lock:
            views = list(self.views.values())
        for v in views:
            v.render(state)

    def load_replay(self, session_id: int) -> dict:
        """A stored session in the shape the view draws (see console.store.SessionRecord)."""
        return record_view(self.workflow.store.load_session(session_id))

    def stop(self) -> None:
        """Stop serving; the workflow's Bullet clients are disconnected (the app is its last user)."""
        self.workflow.remove_listener(self._on_state)
        with self._views_lock:
            for v in self.views.values():
                v.stop_preview()
        self.server.stop()
        close = getattr(self.workflow, "close", None)
        if close is not None:
            close()


__all__ = ["ConsoleApp", "ClientView", "ConsoleError", "check_host", "md", "results_markdown", "robot_markdown",
           "status_markdown", "decisions_markdown", "record_view", "MIN_PASSPHRASE"]
