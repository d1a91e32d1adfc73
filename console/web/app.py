"""The operator console: a viser web app over `console.workflow.machine.Workflow`.

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
import traceback
from types import MappingProxyType
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence

from shelfpick.console.web.markdown import deviation_markdown, results_markdown, robot_markdown, status_markdown
from shelfpick.console.web.panels import (OperatorPanel, PreviewPlayer, SessionsPanel, ShelfDrawing, SupervisorPanel,
                                          executed_markdown, md, quoted)
from shelfpick.console.web.replay_view import LookView, ReplayView, record_view, replay_status
from shelfpick.console.web.segmentation_view import segmentation_image, set_aside_boxes, set_aside_entries
from shelfpick.console.workflow.look import as_planned
from shelfpick.console.workflow.machine import PlanEntry, State, Workflow, WorkflowError
from shelfpick.perception.errors import ShelfpickError
from shelfpick.perception.scene import Camera, Scene

if TYPE_CHECKING:
    import viser

    from shelfpick.perception.capture import Capture
    from shelfpick.planning.plan import Plan

LOCAL_HOSTS = frozenset({"127.0.0.1", "localhost", "::1"})
MIN_PASSPHRASE = 12          # characters, when the console listens beyond this machine


class ConsoleError(ShelfpickError):
    """A console start-up setting the user must change."""


def check_host(host: str, passphrase: str | None, where: str = "--supervisor-passphrase") -> None:
    """Listening beyond this machine requires a supervisor passphrase chosen by a person, and not
    a trivial one (`trivial_passphrase`); `where` names where it came from in the refusal."""
    if host in LOCAL_HOSTS:
        return
    if not passphrase:
        raise ConsoleError(f"--host {host}: listening on a non-local address needs a supervisor passphrase "
                           f"(--supervisor-passphrase-file, SHELFPICK_SUPERVISOR_PASSPHRASE or --supervisor-passphrase)")
    why = trivial_passphrase(passphrase)
    if why:
        raise ConsoleError(f"{where}: refused when listening on {host}: {why}")


_SEQUENCES = ("abcdefghijklmnopqrstuvwxyz", "0123456789", "qwertyuiopasdfghjklzxcvbnm", "azertyuiopqsdfghjklmwxcvbn",
              "qwertzuiopasdfghjklyxcvbnm")
_WORDS = re.compile(r"(?:password|passphrase|passwort|supervisor|shelfpick|letmein|changeme|secret|admin|"
                    r"qwerty|welcome|robot|console)+")
MIN_DISTINCT = 5             # different characters a passphrase needs beyond this machine


def trivial_passphrase(passphrase: str) -> str | None:
    """Why a passphrase is too easy to guess, or None. Trivial: fewer than MIN_PASSPHRASE characters
    (blanks at the ends not counted), fewer than MIN_DISTINCT different characters, a piece said
    twice or more (`abcdefabcdef`), a run along the alphabet, the digits or a keyboard row
    (`abcdefghijkl`, `qwertyuiopas`, either way), or only common words (`password`, `shelfpick`, ...)
    with digits and punctuation around them."""
    p = passphrase.strip()
    if len(p) < MIN_PASSPHRASE:
        return f"at least {MIN_PASSPHRASE} characters (not counting blanks at the ends), got {len(p)}"
    if len(set(p)) < MIN_DISTINCT:
        return f"at least {MIN_DISTINCT} different characters, got {len(set(p))}"
    period = next((d for d in range(1, len(p) // 2 + 1) if p == (p[:d] * (len(p) // d + 1))[:len(p)]), None)
    if period is not None:
        return "it repeats a piece of itself"
    low = p.lower()
    if any(low in seq * 3 or low in (seq * 3)[::-1] for seq in _SEQUENCES):
        return "a run along the alphabet, the digits or a keyboard row"
    letters = re.sub(r"[^a-z]", "", low)
    if letters and _WORDS.fullmatch(letters):
        return "only common words, digits and punctuation"
    return None


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

    def __init__(self, app: ConsoleApp, client: viser.ClientHandle) -> None:
        self.app = app
        self.client = client
        self.wf: Workflow = app.workflow
        self.lock = threading.RLock()
        self.closed = False                        # its browser went away or the server stops: draw nothing
        self.shown_scene: Scene | None = None
        self.shown_capture: Capture | None = None
        self.shown_aside: frozenset[str] = frozenset()    # the boxes the Segmentation image shows set aside
        self.shown_plans: Mapping[str, PlanEntry] | None = None
        self.replay: ReplayView | None = None      # a stored session drawn instead of the live state
        self.shown_look: LookView | None = None    # the replayed look after a step that is drawn
        self.was_running = False                   # the robot was running at the last live render
        self.client_key = f"browser-{getattr(client, 'client_id', id(client))}"   # for the throttle
        self.wf.throttle.connected(self.client_key)      # a browser open before a flood keeps its say
        self.drawing = drawing = ShelfDrawing(client)
        g = client.gui
        tabs = g.add_tab_group()
        with tabs.add_tab("Operator"):
            self.operator = OperatorPanel(g, self.wf, self._do, lambda gui: PreviewPlayer(
                gui, self.lock, drawing, self._preview_source, self._scene, self._highlight, self._no_preview))
        self.preview = self.operator.preview
        with tabs.add_tab("Supervisor"):
            self.supervisor = SupervisorPanel(g, self.wf, self._do, lambda: self.client_key)
        with tabs.add_tab("Sessions"):
            self.sessions = SessionsPanel(g, self.wf)
        self.sessions.btn_replay.on_click(self._replay)
        self.sessions.btn_live.on_click(self._live)
        self.sessions.btn_export.on_click(lambda e: self._do(e, self._export))
        # this browser's 3D view shows the plan its supervisor is deciding on
        self.supervisor.approve_plan.on_update(lambda e: self.preview.follow(self.supervisor.approve_plan.value))
        self.observed: tuple[Scene, Scene] | None = None   # (the last look's shelf, it with the plan's ids)
        self.sessions.look_pick.on_update(lambda e: self._show_look(self.sessions.look_pick.value))
        client.scene.set_up_direction("+z")

    # --------------------------------------------------------------- actions
    def notify(self, title: str, body: str, color: str = "red") -> None:
        try:
            self.client.add_notification(title, body, color=color, auto_close_seconds=8.0)
        except Exception:  # noqa: BLE001 - a closed browser
            pass

    def _do(self, event: Any, fn: Callable[..., Any], *args: Any) -> None:
        try:
            fn(*args)
        except (WorkflowError, ShelfpickError) as exc:
            self.notify("Not done", quoted(exc))
        except Exception as exc:  # noqa: BLE001 - the server keeps running
            traceback.print_exc()
            self.notify("Error", f"{exc.__class__.__name__}: {exc}")

    def _approve(self, event: Any) -> None:
        self.supervisor.approve(event)

    def _reject(self, event: Any) -> None:
        self.supervisor.reject(event)

    def _click_box(self, box_id: str) -> None:
        if self.replay is not None:
            self.notify("Not done", "a replayed session: press “Back to live” (Sessions tab) to pick a target")
            return
        try:
            self.wf.select_target(box_id)
        except (WorkflowError, ShelfpickError) as exc:
            self.notify("Not done", quoted(exc))

    def stop_preview(self) -> None:
        """The preview thread ends at its next frame (the browser went away or the server stops)."""
        self.preview.playing = False

    def close(self) -> None:
        """Its browser went away or the server stops: once a render under way has ended, no other
        starts (a state change on another thread drew on a connection already closed)."""
        with self.lock:
            self.closed = True
            self.stop_preview()
            self.operator.answers.close()      # a click's answer that comes after it

    # ---------------------------------------------------------------- render
    def _preview_source(self, name: str) -> tuple[Any, ...]:
        """(preview step results, plan) for the chosen planner, live or replayed."""
        if self.replay is not None:
            r = self.replay.plans.get(name)
            return (r.preview, r.plan, r.shown) if r else ((), None)
        e = (previewable(self.wf.state) or {}).get(name)
        return (e.preview, e.plan, e.collapse_steps) if e else ((), None)

    def _no_preview(self) -> str:
        if self.replay is not None:
            return "_No preview: this session has no plans._"
        return no_preview_words(self.wf.state)

    def _scene(self) -> Scene | None:
        """The shelf the preview starts from and goes back to: the replayed one, or the shelf as
        last seen (after a robot step the look's, not the capture's)."""
        if self.replay is not None:
            return self.replay.scene
        return self._shelf_now(self.wf.state)

    def _draw_scene(self, scene: Scene | None, camera: Camera | None, caption: str = "") -> None:
        self.drawing.draw(scene, camera, self.shown_scene is None, self._click_box, caption)

    def _highlight(self) -> None:
        target = self.replay.target if self.replay is not None else self.wf.state.target
        risk = set(self.preview.risk)
        st = self.wf.state
        dev = st.deviation if self.replay is None and st.robot == "held" else None   # shown while held
        look = self.shown_look if self.replay is not None else None
        if look is not None:
            risk = set(look.differ_o)
        if dev is not None and self.wf.state.session_id == dev.session:
            risk |= {d.observed for d in dev.verification.boxes if d.status in ("moved", "new")}
        # the faces the plans set aside, on the shelf they were planned on (not on a replayed look's)
        drawn = self.shown_scene if self.replay is None else (self.replay.scene if look is None else None)
        self.drawing.mark(target, risk, dev, drawn, set_aside_entries(self._offered_plans()))

    def _offered_plans(self) -> list[Plan]:
        """The plans the view shows: the replayed session's, or the live ones the preview offers."""
        if self.replay is not None:
            return [r.plan for r in self.replay.plans.values() if r.plan is not None]
        return [e.plan for e in (previewable(self.wf.state) or {}).values() if e.plan is not None]

    def render(self, state: State) -> None:
        with self.lock:
            if self.closed:
                return
            try:
                self._render(state)
            except Exception:  # noqa: BLE001 - a client that went away mid-update
                traceback.print_exc()

    def _render(self, state: State) -> None:
        live = self.replay is None
        op = self.operator
        # a replay shows the stored session only: no live status, no live robot (the audit stays)
        op.status.content = status_markdown(state) if live else replay_status(state, self.replay)
        op.progress.visible = state.planning and live
        op.progress.value = 100.0 * state.progress
        for b in (op.btn_extract, op.btn_clear):
            b.disabled = state.planning or not live
        op.btn_capture.disabled = not live
        op.target.disabled = not live
        op.robot_md.content = robot_markdown(state) if live else self.replay.robot_md
        op.deviation_md.content = deviation_markdown(state) if self.replay is None else ""
        op.answers.replays(None if live else self.replay.id)
        op.answers.show(state)
        self.supervisor.render(state)
        self.sessions.render(state)
        if not live:
            return
        op.results.content = plans_markdown(state)
        self._show_images(state)
        scene = self._shelf_now(state)
        if scene is not self.shown_scene:
            self._draw_scene(scene, state.capture.camera if state.capture is not None else None)
            self.shown_scene = scene
            self.shown_plans = None
            op.show_targets(state.scene)
        self.drawing.set_base(shelf_caption(state, scene))
        running = state.robot == "running"
        if running and not self.was_running:
            self.preview.show_shelf()          # the robot is working on the shelf: not a preview's frame
        self.was_running = running
        op.follow_target(state.target)
        offered = previewable(state)
        if offered is not self.shown_plans:
            self.shown_plans = offered
            self.preview.show_plans(offered)
            self.preview.load()
        self._highlight()

    def _show_images(self, state: State) -> None:
        """The Camera folder again when the capture, or the faces the offered plans set aside,
        change: those masks drawn as grey matter in the Segmentation image (segmentation_view), as
        the 3D view draws them; perception's own overlay while none is set aside."""
        aside = set_aside_boxes(self._offered_plans())
        new = state.capture is not self.shown_capture
        if not new and aside == self.shown_aside:
            return
        self.shown_capture, self.shown_aside = state.capture, aside
        rgb = state.capture.rgb if state.capture is not None else None
        self.operator.show_images(rgb if new else None,
                                  segmentation_image(rgb, state.overlay, state.labels, state.matter, state.scene, aside))

    def _shelf_now(self, state: State) -> Scene | None:
        """The shelf as last seen: after a robot step the look's shelf (with the plan's ids on the
        boxes it matched), else the capture's."""
        if state.observed is None or not state.verifications or state.observed is state.scene:
            return state.scene
        if self.observed is None or self.observed[0] is not state.observed:
            self.observed = (state.observed, as_planned(state.observed, state.verifications[-1]))
        return self.observed[1]

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
            if self.closed:
                return
            self.replay, self.shown_look = rec, None
            self.drawing.replayed = rec.id
            self.operator.show_images(rec.rgb, rec.overlay)
            self._draw_scene(rec.scene, rec.camera, f"Replayed session {v}: the shelf as captured")
            self.shown_scene = None
            self.shown_capture = None
            self.shown_plans = None
            self.operator.results.content = rec.plans_md
            self.sessions.start_replay(rec.summary_md, [lk.label for lk in rec.looks], rec.rgb, rec.overlay)
            self.preview.load(force=True)     # another shelf: from its first frame, even for the same plan
            self.render(self.wf.state)

    def _show_look(self, label: str) -> None:
        """Replay: the shelf observed after one step with the plan's predicted poses as outlines."""
        with self.lock:
            if self.replay is None or self.closed:
                return
            self.sessions.clear_look()
            look = next((lk for lk in self.replay.looks if lk.label == label), None)
            self.shown_look = look
            if look is None or look.observed is None:
                self._draw_scene(self.replay.scene, self.replay.camera, "Replayed session: the shelf as captured")
            else:
                self._draw_scene(look.observed, self.replay.camera,
                                 f"Replayed session: the shelf seen after {look.label}; outlines: as predicted")
                self.sessions.show_look(self.client.scene, look.predicted, look.md)
            self._highlight()

    def _export(self) -> None:
        name = self.sessions.export(self.client)
        self.notify("Exported", f"{name}: the session as one web page (your browser's downloads)", color="green")

    def _live(self, event: Any) -> None:
        with self.lock:
            if self.closed:                   # the click came as the browser went away
                return
            self.replay, self.shown_look = None, None
            self.drawing.replayed = None
            self.sessions.end_replay()
            self.shown_scene = None       # draw the live shelf again
            self.preview.load(force=True)     # the live plan from its first frame, not where the replay was
            self.render(self.wf.state)


NOTHING_TO_PREVIEW: Mapping[str, PlanEntry] = MappingProxyType({})


def previewable(state: State) -> Mapping[str, PlanEntry] | None:
    """The plans the preview offers: none once a run has changed the shelf (they were planned on a
    shelf that is gone, and replaying one would draw its boxes back where they stood); after a
    hold, the `continue` plan."""
    return NOTHING_TO_PREVIEW if state.run_end is not None and state.needs_recapture else state.plans


def no_preview_words(state: State) -> str:
    """Why the live preview has nothing to show: no plans yet, or plans of a shelf a run changed."""
    if state.run_end is not None and state.needs_recapture:
        return "_No preview: the run changed the shelf these plans were made for; capture and plan again._"
    if state.planning:
        return "_No preview yet: planning…_"
    return "_No preview: plan first._"


def shelf_caption(state: State, drawn: Scene | None) -> str:
    """What the live 3D view's shelf is: the capture's, a look's after a robot step, or a capture
    the robot has since changed."""
    if drawn is not None and state.verifications and (drawn is not state.scene or state.observed is state.scene):
        return f"The shelf as seen after robot step {len(state.verifications)}"
    if state.run_end is not None and state.needs_recapture:
        return "The shelf as captured before the run: capture again to see it now"
    return "The shelf as seen"


def plans_markdown(state: State) -> str:
    """The operator's plan panel: the plans up for review and, once a run ended, the plan it
    executed and how it ended, in place of that plan (the run used its approval up, so it is no
    longer up for review: the supervisor's `Plan` offers nothing until a new capture and plan, or
    after a hold only `continue`, which is shown below it)."""
    end = state.run_end
    if end is None:
        return results_markdown(state)
    if state.needs_recapture:
        return (executed_markdown(end) + "\n\n_Nothing to review: the shelf has changed. Capture and plan "
                "again before the next run._")
    rest = ""
    if end.status == "held" and "continue" in (state.plans or {}):
        rest = (f" _The rest of it is offered below as “continue”, in the ids of the capture the look "
                f"made (session {md(state.session_id)})._")
    return executed_markdown(end) + rest + "\n\n" + results_markdown(state)


class ConsoleApp:
    """The viser server, one `ClientView` per browser, all fed by one workflow."""

    def __init__(self, workflow: Workflow, host: str = "127.0.0.1", port: int = 8080,
                 passphrase_set: bool = True, verbose: bool = False, allow_origins: Sequence[str] = ()) -> None:
        """passphrase_set: a person chose the workflow's passphrase (a generated one is for localhost);
        allow_origins: browser origins besides the console's own that may drive it (console.web.origin_guard)."""
        check_host(host, workflow._passphrase if passphrase_set else None)
        from shelfpick.console.web.origin_guard import guarded_viser_server, policy_for

        try:
            policy = policy_for(host, allow_origins)
        except ValueError as exc:
            raise ConsoleError(f"--allow-origin {exc}") from None
        self.workflow = workflow
        self.server = guarded_viser_server(host, port, policy, verbose=verbose)
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

    def _connect(self, client: viser.ClientHandle) -> None:
        view = ClientView(self, client)
        with self._views_lock:
            self.views[client.client_id] = view
        view.render(self.workflow.state)

    def _disconnect(self, client: viser.ClientHandle) -> None:
        with self._views_lock:
            view = self.views.pop(client.client_id, None)
        if view is not None:
            view.close()
            self.workflow.throttle.disconnected(view.client_key)

    def _on_state(self, state: State) -> None:
        with self._views_lock:
            views = list(self.views.values())
        for v in views:
            v.render(state)

    def load_replay(self, session_id: int) -> ReplayView:
        """A stored session in the shape the view draws (see console.store.sessions.SessionRecord)."""
        return record_view(self.workflow.store.load_session(session_id))

    def stop(self) -> None:
        """Stop serving; the workflow's Bullet clients are disconnected (the app is its last user)."""
        self.workflow.remove_listener(self._on_state)
        with self._views_lock:
            views = list(self.views.values())
        for v in views:
            v.close()
        self.server.stop()
        self.workflow.close()


__all__ = ["ConsoleApp", "ClientView", "ConsoleError", "check_host", "plans_markdown", "trivial_passphrase",
           "MIN_PASSPHRASE"]
