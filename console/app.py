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

import re
import threading
import time
import traceback
from typing import Any, Mapping

import numpy as np

from console import scene_view as sv
from console.workflow import PLANNERS, SECONDS_PER_BOX, State, Workflow, WorkflowError, problem_text
from perception.errors import ShelfpickError

LOCAL_HOSTS = {"127.0.0.1", "localhost", "::1"}
PLACEHOLDER = np.full((48, 64, 3), 220, dtype=np.uint8)
MIN_PASSPHRASE = 12          # characters, when the console listens beyond this machine
MAX_SHOWN = 500              # characters of any outside text shown in the page
WORD_JOINER = "\u2060"
_AUTOLINK = re.compile(r"(?i)(?:https?|ftp|mailto|xmpp)(?=:)|www(?=\.)")   # what remark-gfm links


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


def md(value: Any) -> str:
    """Outside text (robot messages, names, reasons, box ids, file names) as literal markdown text.

    viser renders markdown with raw HTML enabled and unsanitised, so every
    ASCII punctuation character becomes a numeric character reference: no
    tag, link, image, emphasis or table cell can start inside it, and the
    browser shows exactly the characters that came in. Line breaks and
    control characters become spaces; long text is clipped. remark-gfm turns
    URLs and e-mail addresses in decoded text into links, so an invisible
    word joiner (U+2060) goes before the ":" of a scheme, the "." of "www."
    and every "@": the text reads the same and links nowhere.
    """
    s = "" if value is None else str(value)
    if len(s) > MAX_SHOWN:
        s = s[:MAX_SHOWN] + "..."
    s = _AUTOLINK.sub(lambda m: m.group(0) + WORD_JOINER, s).replace("@", WORD_JOINER + "@")
    out = []
    for ch in s:
        o = ord(ch)
        if o < 32 or o == 127 or 0x2028 <= o <= 0x2029:
            out.append(" ")
        elif ch.isascii() and not ch.isalnum() and ch != " ":
            out.append(f"&#{o};")
        else:
            out.append(ch)
    return "".join(out)


def _pct(p: float) -> str:
    return f"{100.0 * p:.0f}%"


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
        f"{md(p.box)} {_pct(p.collapse_prob)}" for p in e.plan.predicted) or "—")
    row("max risk", lambda e: _pct(e.plan.risk))
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


def decisions_markdown(decisions: Any, key: str = "plan") -> str:
    """Supervisors' decisions; names and reasons are outside text."""
    return "\n".join(
        f"- {md(d['decision'])} `{md(d.get(key))}` by {md(d.get('who'))}"
        + (f" at {md(d['at'])}" if isinstance(d.get("at"), str) else "")
        + (f": {md(d['reason'])}" if d.get("reason") else "")
        for d in decisions)


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
        self.client_key = f"browser-{getattr(client, 'client_id', id(client))}"   # for the throttle
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
            self.deviation_md = g.add_markdown("")
            with g.add_folder("Camera"):
                self.img_rgb = g.add_image(PLACEHOLDER, label="RGB")
                self.img_overlay = g.add_image(PLACEHOLDER, label="Segmentation")
        with tabs.add_tab("Supervisor"):
            self.sup_info = g.add_markdown("")
            self.who = g.add_text("Name", "supervisor")
            self.passphrase = g.add_text("Passphrase", "")
            self.approve_plan = g.add_dropdown("Plan", PLANNERS + ("continue",), initial_value=PLANNERS[0])
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
            self.look_pick = g.add_dropdown("Look after step", ("—",), initial_value="—",
                                            hint="replay: the observed shelf after a step, the predicted "
                                                 "poses as blue outlines, what differs in red")
            self.btn_live = g.add_button("Back to live")
            self.replay_md = g.add_markdown("")
            self.look_md = g.add_markdown("")

        self.btn_capture.on_click(lambda e: self._do(e, self.wf.capture))
        self.btn_extract.on_click(lambda e: self._do(e, self.wf.plan, "extract"))
        self.btn_clear.on_click(lambda e: self._do(e, self.wf.plan, "clear"))
        self.btn_stop.on_click(lambda e: self._do(e, self.wf.stop, "operator"))
        self.btn_approve.on_click(self._approve)
        self.btn_reject.on_click(self._reject)
        self.btn_replay.on_click(self._replay)
        self.btn_live.on_click(self._live)
        self.look_pick.on_update(lambda e: self._show_look(self.look_pick.value))
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

    def _take_passphrase(self) -> str:
        """The typed passphrase, and the field cleared at once: every use needs it typed again."""
        given = self.passphrase.value
        self.passphrase.value = ""
        return given

    def _approve(self, event: Any) -> None:
        given = self._take_passphrase()

        def go() -> None:
            entry = self._entry_for_approval()
            self.wf.approve(entry.hash, given, self.who.value.strip() or "supervisor",
                            accept_risk=bool(self.accept_risk.value), client=self.client_key)
            self.accept_risk.value = False
            self.wf.execute()
        self._do(event, go)

    def _reject(self, event: Any) -> None:
        given = self._take_passphrase()

        def go() -> None:
            if not self.reason.value.strip():
                raise WorkflowError("Reject needs a reason: type it in `Reject reason`")
            entry = self._entry_for_approval()
            self.wf.reject(entry.hash, given, self.who.value.strip() or "supervisor",
                           self.reason.value, client=self.client_key)
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
            txt = f"Step {fr.step + 1}/{nsteps}: pulling **{md(fr.box)}** · t = {fr.t:.2f} s"
            if fr.collapsed:
                txt += f" · **collapsed: {', '.join(md(b) for b in fr.collapsed)}**"
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
        risk = set(getattr(self, "risk", set()))
        dev = self.wf.state.deviation if self.replay is None else None
        look = self.replay.get("shown_look") if self.replay is not None else None
        if look is not None:
            risk = set(look["differ_o"])
        if dev is not None and self.wf.state.session_id == dev.session:
            risk |= {d.observed for d in dev.verification.boxes if d.status in ("moved", "new")}
        self._draw_predicted(dev)
        for bid, n in self.nodes.items():
            n.target.visible = bid == target
            n.risk.visible = bid in risk

    def _draw_predicted(self, dev: Any) -> None:
        """Blue outlines where the held step's prediction had the boxes that differ (once per deviation)."""
        if dev is getattr(self, "shown_deviation", None):
            return
        for h in getattr(self, "predicted_nodes", []):
            h.remove()
        self.predicted_nodes = []
        self.shown_deviation = dev
        if dev is None or dev.predicted is None:
            return
        differ = {d.predicted for d in dev.verification.boxes if d.status in ("moved", "missing")}
        self.predicted_nodes = sv.draw_outlines(self.client.scene, [b for b in dev.predicted.boxes
                                                                    if b.id in differ])

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
        self.deviation_md.content = deviation_markdown(state) if self.replay is None else ""
        self.sup_info.content = self._supervisor_text(state)
        self.decisions_md.content = decisions_markdown(state.decisions) or "_No decisions for this capture._"
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
            lines.append(f"- **{md(name)}** `{md(e.hash)}`: {' → '.join(md(b) for b in e.plan.sequence)} "
                         f"(max risk {_pct(e.plan.risk)}{'' if e.plan.safe else ', predicted UNSAFE'}){mark}")
        if state.scene_problems:
            lines.append("\n**⚠ The shelf does not stand as seen:** " + "; ".join(
                md(problem_text(p)) for p in state.scene_problems)
                + ". Approving needs `Accept predicted risk`.")
        lines.append("\n`Approve` sends the chosen plan to the robot at once.")
        return "\n".join(lines)

    # ---------------------------------------------------------------- replay
    def _refresh_sessions(self) -> None:
        try:
            rows = self.wf.store.list_sessions()
        except Exception as exc:  # noqa: BLE001 - DB locked/unreadable
            self.sessions_md.content = f"**⚠ database: {md(exc)}**"
            return
        rows = sorted(rows, key=lambda r: -int(r["id"]))
        lines = ["| id | started | source | boxes | task | status |", "|---|---|---|---|---|---|"]
        for r in rows[:12]:
            lines.append(f"| {md(r['id'])} | {md(_fmt_time(r.get('started')))} | {md(r.get('source', ''))} | "
                         f"{md(r.get('n_boxes', ''))} | {md(r.get('task') or '')} | {md(r.get('status') or '')} |")
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
            self._clear_look()
            self.look_pick.options = ("—",) + tuple(lk["label"] for lk in rec.get("looks", ()))
            self.look_pick.value = "—"
            self._load_preview()
            self.render(self.wf.state)

    def _clear_look(self) -> None:
        for h in getattr(self, "look_nodes", []):
            h.remove()
        self.look_nodes = []
        self.look_md.content = ""

    def _show_look(self, label: str) -> None:
        """Replay: the shelf observed after one step with the plan's predicted poses as outlines."""
        with self.lock:
            if self.replay is None:
                return
            self._clear_look()
            look = next((lk for lk in self.replay.get("looks", ()) if lk["label"] == label), None)
            self.replay["shown_look"] = look
            if look is None or look["observed"] is None:
                self._draw_scene(self.replay.get("scene"), self.replay.get("camera"))
            else:
                self._draw_scene(look["observed"], self.replay.get("camera"))
                if look["predicted"] is not None:
                    self.look_nodes = sv.draw_outlines(self.client.scene, look["predicted"].boxes, prefix="/look")
                self.look_md.content = look["md"]
            self._highlight()

    def _live(self, event: Any) -> None:
        with self.lock:
            self.replay = None
            self.replay_md.content = ""
            self._clear_look()
            self.look_pick.options = ("—",)
            self.look_pick.value = "—"
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
        lines.append(f"| {i + 1} | {md(box)} | {_pct(p.collapse_prob) if p else '—'} | {md(actual)} |")
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


def _fmt_time(t: Any) -> str:
    if isinstance(t, (int, float)):
        return time.strftime("%Y-%m-%d %H:%M:%S", time.localtime(t))
    return str(t or "")


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
        """Stop serving; the workflow's Bullet clients are disconnected (the app is its last user)."""
        self.workflow.remove_listener(self._on_state)
        with self._views_lock:
            for v in self.views.values():
                v.playing = False
        self.server.stop()
        close = getattr(self.workflow, "close", None)
        if close is not None:
            close()


__all__ = ["ConsoleApp", "ClientView", "ConsoleError", "check_host", "md", "results_markdown", "robot_markdown",
           "status_markdown", "decisions_markdown", "record_view", "MIN_PASSPHRASE"]
