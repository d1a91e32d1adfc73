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

import html
import threading
import time
import traceback
from typing import Any

import numpy as np

from console import scene_view as sv
from console.workflow import PLANNERS, SECONDS_PER_BOX, State, Workflow, WorkflowError
from perception.errors import ShelfpickError

LOCAL_HOSTS = {"127.0.0.1", "localhost", "::1"}
PLACEHOLDER = np.full((48, 64, 3), 220, dtype=np.uint8)


class ConsoleError(ShelfpickError):
    """A console start-up setting the user must change."""


def check_host(host: str, passphrase_set: bool) -> None:
    """Listening beyond this machine requires a supervisor passphrase chosen by a person."""
    if host not in LOCAL_HOSTS and not passphrase_set:
        raise ConsoleError(f"--host {host}: listening on a non-local address needs a supervisor "
                           "passphrase (--supervisor-passphrase or SHELFPICK_SUPERVISOR_PASSPHRASE)")


def _pct(p: float) -> str:
    return f"{100.0 * p:.0f}%"


def results_markdown(state: State) -> str:
    """The two plans side by side."""
    if state.planning:
        return f"**Planning…** {html.escape(state.progress_text)}"
    if not state.plans:
        return "_No plans yet. Select a target, then press `Plan extraction` or `Plan clearance`._"
    cols = [p for p in PLANNERS if p in state.plans]
    rows = ["| | " + " | ".join(cols) + " |", "|---|" + "---|" * len(cols)]

    def row(name: str, fn) -> None:
        rows.append(f"| {name} | " + " | ".join(fn(state.plans[c]) for c in cols) + " |")

    row("sequence", lambda e: " → ".join(e.plan.sequence) or "—")
    row("boxes removed", lambda e: str(len(e.plan.sequence)))
    row("collapse risk per step", lambda e: ", ".join(
        f"{p.box} {_pct(p.collapse_prob)}" for p in e.plan.predicted) or "—")
    row("max risk", lambda e: _pct(e.plan.risk))
    row("predicted safe", lambda e: "yes" if e.plan.safe else "**NO**")
    row(f"est. execution ({SECONDS_PER_BOX:g} s/box)", lambda e: f"{e.est_seconds:.1f} s")
    row("planning time", lambda e: f"{_planning_seconds(e.plan):.2f} s")
    row("plan hash", lambda e: f"`{e.hash}`")
    return "\n".join(rows)


def _planning_seconds(plan: Any) -> float:
    """Search time plus the depth-sample set-up it needed (both in the plan's timing)."""
    t = dict(plan.timing or {})
    return float(t.get("planning_s", 0.0)) + float(t.get("setup_s", 0.0))


def robot_markdown(state: State) -> str:
    lines = [f"**Robot:** {state.robot}"]
    for ev in state.robot_events[-8:]:
        step = f" step {ev.step + 1}" if isinstance(ev.step, int) else ""
        lines.append(f"- {ev.kind}{step}" + (f" `{ev.box}`" if ev.box else ""))
    out = state.outcome
    if out is not None:
        lines.append(f"\n**Outcome:** {'success' if out.ok else 'not completed'}; "
                     f"completed: {', '.join(out.completed) or 'none'}"
                     + (f"; error: {out.error}" if out.error else ""))
    return "\n".join(lines)


def status_markdown(state: State, viewer: str = "") -> str:
    parts = []
    if state.error:
        parts.append(f"**⚠ {html.escape(state.error)}**")
    if state.message:
        parts.append(html.escape(state.message))
    head = f"Source `{state.source}`"
    if state.session_id is not None:
        head += f" · session {state.session_id}"
    if state.target:
        head += f" · target **{state.target}**"
    parts.append(head + (f" · {viewer}" if viewer else ""))
    for w in state.warnings[:3]:
        parts.append(f"_perception: {html.escape(str(w))}_")
    return "\n\n".join(parts)


class ClientView:
    """Everything one browser sees; rebuilt from the workflow state on every change."""

    def __init__(self, app: "ConsoleApp", client: Any) -> None:
        self.app = app
        self.client = client
        self.wf: Workflow = app.workflow
        self.lock = threading.RLock()
        self.nodes: dict[str, sv.BoxNodes] = {}
        self.shown_scene: Any = None
        self.shown_capture: Any = None
        self.shown_plans: Any = None
        self.frames: list[sv.Keyframe] = []
        self.playing = False
        self.replay: Any = None
        self.last_sessions_key: Any = None
        self._build()

    # ----------------------------------------------------------------- build
    def _build(self) -> None:
        g = self.client.gui
        tabs = g.add_tab_group()
        with tabs.add_tab("Operator"):
            self.status = g.add_markdown("Starting…")
            self.btn_capture = g.add_button("Capture", icon="camera")
            self.target = g.add_dropdown("Target", ("—",), initial_value="—")
            self.btn_extract = g.add_button("Plan extraction", color="blue")
            self.btn_clear = g.add_button("Plan clearance")
            self.progress = g.add_progress_bar(0.0, visible=False, animated=True)
            self.results = g.add_markdown("")
            with g.add_folder("Preview"):
                self.prev_plan = g.add_dropdown("Preview plan", PLANNERS, initial_value=PLANNERS[0])
                self.btn_play = g.add_button("Play", icon="player-play")
                self.btn_pause = g.add_button("Pause", icon="player-pause")
                self.slider = g.add_slider("Preview frame", 0, 1, 1, 0, disabled=True)
                self.prev_info = g.add_markdown("")
            self.btn_stop = g.add_button("Stop robot", color="red", icon="hand-stop")
            self.robot_md = g.add_markdown("")
            with g.add_folder("Camera"):
                self.img_rgb = g.add_image(PLACEHOLDER, label="RGB")
                self.img_overlay = g.add_image(PLACEHOLDER, label="Segmentation")
        with tabs.add_tab("Supervisor"):
            self.sup_info = g.add_markdown("")
            self.who = g.add_text("Name", "supervisor")
            self.passphrase = g.add_text("Passphrase", "")
            self.approve_plan = g.add_dropdown("Plan", PLANNERS, initial_value=PLANNERS[0])
            self.accept_risk = g.add_checkbox("Accept predicted risk", False,
                                              hint="needed to approve a plan predicted unsafe")
            self.btn_approve = g.add_button("Approve", color="green")
            self.reason = g.add_text("Reject reason", "")
            self.btn_reject = g.add_button("Reject", color="orange")
            self.decisions_md = g.add_markdown("")
        with tabs.add_tab("Sessions"):
            self.sessions_md = g.add_markdown("")
            self.session_pick = g.add_dropdown("Session", ("—",), initial_value="—")
            self.btn_replay = g.add_button("Replay")
            self.btn_live = g.add_button("Back to live")
            self.replay_md = g.add_markdown("")

        self.btn_capture.on_click(lambda e: self._do(e, self.wf.capture))
        self.btn_extract.on_click(lambda e: self._do(e, self.wf.plan, "extract"))
        self.btn_clear.on_click(lambda e: self._do(e, self.wf.plan, "clear"))
        self.btn_stop.on_click(lambda e: self._do(e, self.wf.stop, "operator"))
        self.btn_approve.on_click(self._approve)
        self.btn_reject.on_click(self._reject)
        self.btn_replay.on_click(self._replay)
        self.btn_live.on_click(self._live)
        self.btn_play.on_click(lambda e: self._play())
        self.btn_pause.on_click(lambda e: self._pause())
        self.prev_plan.on_update(lambda e: self._load_preview(force=True))
        self.slider.on_update(lambda e: self._show_frame(int(self.slider.value)))

        @self.target.on_update
        def _(event: Any) -> None:
            if event.client is None:      # our own programmatic update
                return
            v = self.target.value
            if v != "—" and v != self.wf.state.target:
                self._do(event, self.wf.select_target, v)

        self.client.scene.set_up_direction("+z")

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

    def _entry_for_approval(self) -> Any:
        entry = self.wf.state.plans.get(self.approve_plan.value)
        if entry is None:
            raise WorkflowError("no plan to decide on: plan first")
        return entry

    def _approve(self, event: Any) -> None:
        def go() -> None:
            entry = self._entry_for_approval()
            self.wf.approve(entry.hash, self.passphrase.value, self.who.value.strip() or "supervisor",
                            accept_risk=bool(self.accept_risk.value))
            self.accept_risk.value = False
            self.wf.execute()
        self._do(event, go)

    def _reject(self, event: Any) -> None:
        def go() -> None:
            if not self.reason.value.strip():
                raise WorkflowError("Reject needs a reason: type it in `Reject reason`")
            entry = self._entry_for_approval()
            self.wf.reject(entry.hash, self.passphrase.value, self.who.value.strip() or "supervisor",
                           self.reason.value)
            self.reason.value = ""
        self._do(event, go)

    def _click_box(self, box_id: str) -> None:
        if self.replay is not None:
            return
        try:
            self.wf.select_target(box_id)
        except (WorkflowError, ShelfpickError) as exc:
            self.notify("Not done", str(exc))

    # --------------------------------------------------------------- preview
    def _preview_source(self) -> tuple[Any, Any]:
        """(preview step results, plan) for the chosen planner, live or replayed."""
        name = self.prev_plan.value
        if self.replay is not None:
            plans = self.replay.get("plans", {})
            e = plans.get(name)
            return (e["preview"], e["plan"]) if e else ((), None)
        e = self.wf.state.plans.get(name)
        return (e.preview, e.plan) if e else ((), None)

    def _load_preview(self, force: bool = False) -> None:
        with self.lock:
            self.playing = False
            preview, plan = self._preview_source()
            self.frames = sv.timeline(preview) if preview else []
            self.risk = sv.risky_boxes(plan) if plan is not None else set()
            n = len(self.frames)
            self.slider.max = max(1, n - 1)
            self.slider.disabled = n == 0
            if self.slider.value != 0:
                self.slider.value = 0          # triggers _show_frame(0)
            elif n:
                self._show_frame(0)
            if not n:
                self.prev_info.content = "_No preview: plan first._"
                scene = self._scene()
                if scene is not None:
                    sv.reset_boxes(self.client, self.nodes, scene)
            self._highlight()

    def _show_frame(self, i: int) -> None:
        with self.lock:
            if not self.frames or not self.nodes:
                return
            i = max(0, min(i, len(self.frames) - 1))
            fr = self.frames[i]
            scene = self._scene()
            sv.apply_keyframe(self.client, self.nodes, fr, scene.shelf, None)
            nsteps = max(k.step for k in self.frames) + 1
            txt = f"Step {fr.step + 1}/{nsteps}: pulling **{fr.box}** · t = {fr.t:.2f} s"
            if fr.collapsed:
                txt += f" · **collapsed: {', '.join(fr.collapsed)}**"
            self.prev_info.content = txt

    def _play(self) -> None:
        with self.lock:
            if self.playing or not self.frames:
                return
            self.playing = True
            if int(self.slider.value) >= len(self.frames) - 1:
                self.slider.value = 0

        def run() -> None:
            while True:
                with self.lock:
                    if not self.playing:
                        return
                    i = int(self.slider.value) + 1
                    if i >= len(self.frames):
                        self.playing = False
                        return
                    self.slider.value = i
                time.sleep(1 / 20)

        threading.Thread(target=run, name="shelfpick-preview", daemon=True).start()

    def _pause(self) -> None:
        with self.lock:
            self.playing = False

    # ---------------------------------------------------------------- render
    def _scene(self) -> Any:
        if self.replay is not None:
            return self.replay.get("scene")
        return self.wf.state.scene

    def _draw_scene(self, scene: Any, camera: Any) -> None:
        sc = self.client.scene
        for n in self.nodes.values():
            n.box.remove()
        self.nodes = {}
        if self.shown_scene is None:
            self.shelf_nodes = []
        for h in getattr(self, "shelf_nodes", []):
            h.remove()
        self.shelf_nodes = []
        if scene is None:
            return
        self.shelf_nodes = sv.draw_shelf(sc, scene.shelf)
        cam = camera or getattr(scene, "camera", None)
        if cam is not None:
            self.shelf_nodes.append(sv.draw_camera(sc, cam))
        self.nodes = sv.draw_boxes(sc, scene)
        for bid, n in self.nodes.items():
            n.box.on_click(lambda ev, bid=bid: self._click_box(bid))

    def _highlight(self) -> None:
        target = self.replay.get("target") if self.replay is not None else self.wf.state.target
        risk = getattr(self, "risk", set())
        for bid, n in self.nodes.items():
            n.target.visible = bid == target
            n.risk.visible = bid in risk

    def render(self, state: State) -> None:
        with self.lock:
            try:
                self._render(state)
            except Exception:  # noqa: BLE001 - a client that went away mid-update
                traceback.print_exc()

    def _render(self, state: State) -> None:
        live = self.replay is None
        self.status.content = status_markdown(state, "" if live else f"**replaying session "
                                              f"{self.replay.get('id')}** (press `Back to live`)")
        self.progress.visible = state.planning
        self.progress.value = 100.0 * state.progress
        for b in (self.btn_extract, self.btn_clear):
            b.disabled = state.planning
        self.robot_md.content = robot_markdown(state)
        self.sup_info.content = self._supervisor_text(state)
        self.decisions_md.content = "\n".join(
            f"- {d['decision']} `{d['plan']}` by {html.escape(str(d['who']))}"
            + (f": {html.escape(str(d['reason']))}" if d.get("reason") else "")
            for d in state.decisions) or "_No decisions for this capture._"
        key = (state.session_id, state.robot, len(state.decisions), state.plans is not None and len(state.plans))
        if key != self.last_sessions_key:
            self.last_sessions_key = key
            self._refresh_sessions()
        if not live:
            return
        self.results.content = results_markdown(state)
        if state.capture is not self.shown_capture:
            self.shown_capture = state.capture
            if state.capture is not None:
                self.img_rgb.image = state.capture.rgb
            self.img_overlay.image = state.overlay if state.overlay is not None else PLACEHOLDER
        if state.scene is not self.shown_scene:
            self._draw_scene(state.scene, state.capture.camera if state.capture is not None else None)
            self.shown_scene = state.scene
            self.shown_plans = None
            ids = tuple(state.scene.ids) if state.scene is not None and state.scene.boxes else ("—",)
            self.target.options = ids
        want = state.target or "—"
        if self.target.value != want and want in self.target.options:
            self.target.value = want
        if state.plans is not self.shown_plans:
            self.shown_plans = state.plans
            self._load_preview()
        self._highlight()

    def _supervisor_text(self, state: State) -> str:
        if not state.plans:
            return "_Nothing to decide: no plans for the current capture._"
        lines = ["Pending plans for this capture:"]
        for name, e in state.plans.items():
            mark = " ✅ approved" if state.approved == e.hash else ""
            lines.append(f"- **{name}** `{e.hash}`: {' → '.join(e.plan.sequence)} "
                         f"(max risk {_pct(e.plan.risk)}){mark}")
        lines.append("\n`Approve` sends the chosen plan to the robot at once.")
        return "\n".join(lines)

    # ---------------------------------------------------------------- replay
    def _refresh_sessions(self) -> None:
        try:
            rows = self.wf.store.list_sessions()
        except Exception as exc:  # noqa: BLE001 - DB locked/unreadable
            self.sessions_md.content = f"**⚠ database: {html.escape(str(exc))}**"
            return
        rows = sorted(rows, key=lambda r: -int(r["id"]))
        lines = ["| id | started | source | boxes | task | status |", "|---|---|---|---|---|---|"]
        for r in rows[:12]:
            lines.append(f"| {r['id']} | {_fmt_time(r.get('started'))} | {r.get('source', '')} | "
                         f"{r.get('n_boxes', '')} | {r.get('task') or ''} | {r.get('status') or ''} |")
        self.sessions_md.content = "\n".join(lines) if rows else "_No sessions yet._"
        opts = tuple(str(r["id"]) for r in rows) or ("—",)
        cur = self.session_pick.value
        self.session_pick.options = opts
        self.session_pick.value = cur if cur in opts else opts[0]

    def _replay(self, event: Any) -> None:
        v = self.session_pick.value
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
            if rec.get("rgb") is not None:
                self.img_rgb.image = rec["rgb"]
            self.img_overlay.image = rec["overlay"] if rec.get("overlay") is not None else PLACEHOLDER
            self._draw_scene(rec.get("scene"), rec.get("camera"))
            self.shown_scene = None
            self.shown_capture = None
            self.shown_plans = None
            self.results.content = rec["plans_md"]
            self.replay_md.content = rec["summary_md"]
            self._load_preview()
            self.render(self.wf.state)

    def _live(self, event: Any) -> None:
        with self.lock:
            self.replay = None
            self.replay_md.content = ""
            self.render(self.wf.state)


def record_view(rec: Any) -> dict:
    """A stored `SessionRecord` in the shape a view draws: images, scene, plans, decisions, outcome."""
    from console.workflow import PlanEntry, State

    plans: dict[str, dict] = {}
    entries: dict[str, PlanEntry] = {}
    for pr in rec.plans:                       # later plans of a planner replace earlier ones
        plans[pr.plan.planner] = {"plan": pr.plan, "preview": pr.preview or (), "hash": pr.hash}
        entries[pr.plan.planner] = PlanEntry(pr.plan, pr.hash, ())
    plans_md = results_markdown(State(plans=entries)) if entries else "_No plans in this session._"
    lines = [f"### Session {rec.id}", f"started {rec.started} · source `{rec.source}` · "
             f"status **{rec.status}** · {rec.n_boxes} boxes" + (f" · {rec.task}" if rec.task else "")]
    if rec.missing_files:
        lines.append(f"**⚠ missing files:** {', '.join(rec.missing_files)}")
    lines.append("\n**Decisions**")
    lines += [f"- {d['decision']} `{d['plan_hash']}` by {html.escape(str(d['who']))} at {d['at']}"
              + (f": {html.escape(str(d['reason']))}" if d.get("reason") else "") for d in rec.decisions] \
        or ["- none"]
    refused = [e for e in rec.robot_events if e["kind"] == "auth_refused"]
    if refused:
        lines.append(f"- {len(refused)} attempt(s) refused: wrong supervisor passphrase")
    out = rec.outcome
    if out:
        lines.append("\n**Robot outcome vs prediction**")
        lines.append(f"{'success' if out.get('ok') else 'not completed'} ({out.get('planner', '?')} plan "
                     f"`{out.get('plan', '')}`); completed: {', '.join(out.get('completed') or []) or 'none'}"
                     + (f"; error: {html.escape(str(out['error']))}" if out.get("error") else ""))
        pred = {}
        for p in plans.values():
            if p["hash"] == out.get("plan"):
                pred = {s.box: s for s in p["plan"].predicted}
        lines.append("\n| step | box | predicted collapse | actual |\n|---|---|---|---|")
        for i, box in enumerate(out.get("sequence") or []):
            st = (out.get("steps") or [])[i] if i < len(out.get("steps") or []) else None
            actual = _actual_text(st) if st is not None else ("not run" if box not in (out.get("completed") or [])
                                                              else "done")
            p = pred.get(box)
            lines.append(f"| {i + 1} | {box} | {_pct(p.collapse_prob) if p else '—'} | {actual} |")
    else:
        lines.append("\n_The robot did not run in this session._")
    target = None
    for p in plans.values():
        target = p["plan"].target or target
    cap = rec.capture
    return {"id": rec.id, "rgb": cap.rgb if cap is not None else None, "overlay": rec.overlay,
            "scene": rec.scene, "camera": cap.camera if cap is not None else rec.scene.camera,
            "target": target, "plans": plans, "plans_md": plans_md, "summary_md": "\n".join(lines)}


def _actual_text(step: Any) -> str:
    if not isinstance(step, dict):
        return str(step)
    bits = []
    if "extracted" in step:
        bits.append("extracted" if step["extracted"] else "NOT extracted")
    if step.get("collapsed"):
        bits.append("collapsed: " + ", ".join(step["collapsed"]))
    if step.get("error"):
        bits.append(f"error: {step['error']}")
    return "; ".join(bits) or "done"


def _fmt_time(t: Any) -> str:
    if isinstance(t, (int, float)):
        return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))
    return str(t or "")


class ConsoleApp:
    """The viser server, one `ClientView` per browser, all fed by one workflow."""

    def __init__(self, workflow: Workflow, host: str = "127.0.0.1", port: int = 8080,
                 passphrase_set: bool = True, verbose: bool = False) -> None:
        check_host(host, passphrase_set)
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
            view.playing = False

    def _on_state(self, state: State) -> None:
        with self._views_lock:
            views = list(self.views.values())
        for v in views:
            v.render(state)

    def load_replay(self, session_id: int) -> dict:
        """A stored session in the shape the view draws (see console.store.SessionRecord)."""
        return record_view(self.workflow.store.load_session(session_id))

    def stop(self) -> None:
        self.workflow.remove_listener(self._on_state)
        with self._views_lock:
            for v in self.views.values():
                v.playing = False
        self.server.stop()


__all__ = ["ConsoleApp", "ClientView", "ConsoleError", "check_host", "results_markdown"]
