"""The parts of one browser's console page, each owning its own GUI handles.

`console.web.app.ClientView` composes them: the operator panel (capture, plan,
stop, camera images), the preview player inside it, the supervisor panel
(approve / reject), the sessions panel (stored sessions, replay, looks after
each step) and the 3D shelf they all draw on. What crosses panels (replay
mode, which scene is shown) stays with the view; a panel gets it through the
callables it is built with.
"""
from __future__ import annotations

import re
import threading
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from shelfpick.console.web import scene_view as sv
from shelfpick.console.web.risk_text import plan_risk, risk_words
from shelfpick.console.web.time_words import start_time_words
from shelfpick.console.workflow.machine import (PLANNERS, Deviation, PlanEntry, State, Workflow, WorkflowError,
                                               problem_text)
from shelfpick.console.workflow.state import RunEnd
from shelfpick.perception.scene import Camera, Scene
from shelfpick.planning.plan import Plan

if TYPE_CHECKING:
    import viser

PLACEHOLDER = np.full((48, 64, 3), 220, dtype=np.uint8)
MAX_SHOWN = 500              # characters of any outside text shown in the page
WORD_JOINER = "\u2060"
_AUTOLINK = re.compile(r"(?i)(?:https?|ftp|mailto|xmpp)(?=:)|www(?=\.)")   # what remark-gfm links
Do = Callable[..., None]     # run a call for a GUI event: (event, fn, *args), errors shown in that browser


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
    out: list[str] = []
    for ch in s:
        o = ord(ch)
        if o < 32 or o == 127 or 0x2028 <= o <= 0x2029:
            out.append(" ")
        elif ch.isascii() and not ch.isalnum() and ch != " ":
            out.append(f"&#{o};")
        else:
            out.append(ch)
    return "".join(out)


_QUOTED = re.compile(r"`([^`\n]{1,80})`")


def quoted(text: object) -> str:
    """Our message as plain text: the names of buttons it quotes in `backticks` in quotes instead."""
    return _QUOTED.sub(lambda m: f"\u201c{m.group(1)}\u201d", "" if text is None else str(text))


def ours(text: object) -> str:
    """A message of our own that may carry outside text (ids, database errors): escaped like all
    outside text, with the names of buttons it quotes in `backticks` shown in quotes, not as backticks."""
    return md(quoted(text))


def _worlds_of(plan: Plan | None) -> int | None:
    """How many sample worlds the search drew (the preview shows the first of them)."""
    search = (plan.extra or {}).get("search", {}) if plan is not None and isinstance(plan.extra, dict) else {}
    n = search.get("worlds") if isinstance(search, dict) else None
    return n if isinstance(n, int) and not isinstance(n, bool) else None


class ShelfDrawing:
    """This browser's 3D shelf: the box nodes, shelf and camera, and the predicted-pose outlines."""

    def __init__(self, client: viser.ClientHandle) -> None:
        self.client = client
        self.nodes: dict[str, sv.BoxNodes] = {}
        self.shelf_nodes: list[viser.SceneNodeHandle] = []
        self.predicted_nodes: list[viser.SceneNodeHandle] = []
        self.shown_deviation: Deviation | None = None
        self.aside_nodes: list[viser.SceneNodeHandle] = []
        self.aside_key: tuple | None = None     # (scene, set-aside boxes) drawn
        self.hidden: set[str] = set()           # boxes drawn as set-aside matter instead
        self.caption_node: viser.LabelHandle | None = None
        self.base_caption = SHELF_AS_SEEN       # what the view shows when no preview frame is drawn
        self.caption = ""                       # the caption's text now
        self.replayed: int | None = None        # the stored session drawn, if a replay is

    def draw(self, scene: Scene | None, camera: Camera | None, forget_shelf: bool,
             on_click: Callable[[str], None], caption: str = "") -> None:
        """Replace the drawn shelf by `scene`; forget_shelf: the old shelf handles were already
        replaced. `caption`: what the drawn shelf is (default: the shelf as seen)."""
        sc = self.client.scene
        for n in self.nodes.values():
            n.box.remove()
        self.nodes = {}
        if forget_shelf:
            self.shelf_nodes = []
        for h in self.shelf_nodes + ([] if forget_shelf else self.aside_nodes):
            h.remove()
        self.shelf_nodes, self.aside_nodes, self.aside_key, self.hidden = [], [], None, set()
        self.caption_node, self.base_caption = None, caption or SHELF_AS_SEEN
        if scene is None:
            return
        self.shelf_nodes = sv.draw_shelf(sc, scene.shelf)
        self.caption = self.base_caption
        self.caption_node = sv.draw_caption(sc, scene.shelf, self.caption)
        self.shelf_nodes.append(self.caption_node)
        cam = camera or scene.camera
        if cam is not None:
            self.shelf_nodes.append(sv.draw_camera(sc, cam))
        self.nodes = sv.draw_boxes(sc, scene)
        self.shelf_nodes.extend(sv.draw_unexplained(sc, scene))   # matter no box explains (issue 31)
        for bid, n in self.nodes.items():
            n.box.on_click(lambda ev, bid=bid: on_click(bid))

    def set_base(self, caption: str) -> None:
        """What the drawn shelf is changed (a run ended, a look came); shown unless a preview frame is."""
        showing_base = self.caption == self.base_caption
        self.base_caption = caption or SHELF_AS_SEEN
        if showing_base:
            self.say(None)

    def say(self, text: str | None) -> None:
        """Caption the view: `text` while a preview frame is drawn, None when the shelf is drawn again.
        A replay's preview is said to be the replayed session's: the 3D view is shared by all tabs,
        and on the Supervisor tab (live) "Preview of the physics plan" read as the live plan."""
        if text and self.replayed is not None:
            text = f"Replayed session {self.replayed}: {text[:1].lower()}{text[1:]}"
        text = text or self.base_caption
        if self.caption_node is not None and text != self.caption:
            self.caption_node.text = text
            self.caption = text

    def mark(self, target: str | None, risk: set[str], dev: Deviation | None,
             scene: Scene | None = None, aside: Sequence[Mapping[str, Any]] = ()) -> None:
        """Target and risky boxes outlined; the held step's predicted poses in blue; faces the plans
        set aside (`aside`: their `extra["set_aside"]` entries) drawn as matter of `scene`."""
        self.draw_predicted(dev)
        self.show_aside(scene, aside)
        for bid, n in self.nodes.items():
            n.target.visible = bid == target
            n.risk.visible = bid in risk

    def show_aside(self, scene: Scene | None, entries: Sequence[Mapping[str, Any]]) -> None:
        """The set-aside faces as grey matter in place of their boxes (once per scene and set)."""
        boxes = tuple(sorted({b for e in entries for b in e.get("boxes", ())})) if scene is not None else ()
        key = (id(scene), boxes) if boxes else None
        if key == self.aside_key:
            return
        for h in self.aside_nodes:
            h.remove()
        for bid in self.hidden:
            if bid in self.nodes:
                self.nodes[bid].box.visible = True
        self.aside_nodes, self.aside_key, self.hidden = [], key, set()
        if not boxes or scene is None:
            return
        from shelfpick.planning.set_aside import SetAside

        aside = SetAside.from_entries(scene, entries)
        self.aside_nodes = sv.draw_set_aside(self.client.scene, aside)
        self.hidden = {b for b in aside.boxes() if b in self.nodes}
        for bid in self.hidden:
            self.nodes[bid].box.visible = False

    def draw_predicted(self, dev: Deviation | None) -> None:
        """Blue outlines where the held step's prediction had the boxes that differ (once per deviation)."""
        if dev is self.shown_deviation:
            return
        for h in self.predicted_nodes:
            h.remove()
        self.predicted_nodes = []
        self.shown_deviation = dev
        if dev is None or dev.predicted is None:
            return
        differ = {d.predicted for d in dev.verification.boxes if d.status in ("moved", "missing")}
        self.predicted_nodes = sv.draw_outlines(self.client.scene, [b for b in dev.predicted.boxes
                                                                    if b.id in differ])


SHELF_AS_SEEN = "The shelf as seen"


def preview_caption(planner: str, frame: sv.Keyframe, nsteps: int) -> str:
    """The 3D view's caption while it draws a preview frame: a prediction, not the shelf."""
    where = f", {frame.world}" if frame.world else ""
    fell = f"; collapsed: {', '.join(frame.collapsed)}" if frame.collapsed else ""
    return (f"Preview of the {planner} plan, step {frame.step + 1}/{nsteps}{where}{fell}"
            " (predicted, not the shelf as seen)")


class PreviewPlayer:
    """The `Preview` folder: a plan's recorded pull frames on the 3D shelf, scrubbed or played at 20 fps."""

    def __init__(self, gui: viser.GuiApi, lock: threading.RLock, drawing: ShelfDrawing,
                 source: Callable[[str], tuple[Sequence[Any], Plan | None]], scene: Callable[[], Scene | None],
                 after_load: Callable[[], None], why_none: Callable[[], str] = lambda: "_No preview: plan first._") -> None:
        self.lock = lock
        self.why_none = why_none        # why there is nothing to preview, in words
        self.drawing = drawing
        self.source = source            # planner name -> (preview step results, plan)
        self.scene = scene
        self.after_load = after_load
        self.frames: list[sv.Keyframe] = []
        self.recorded: set[str] = set()
        self.risk: set[str] = set()
        self.playing = False
        self.loaded: tuple | None = None      # (planner, plan hash, steps) of the preview loaded
        self.prev_plan = gui.add_dropdown("Preview plan", PLANNERS, initial_value=PLANNERS[0])
        self.btn_play = gui.add_button("Play", icon="player-play")
        self.btn_pause = gui.add_button("Pause", icon="player-pause")
        self.slider = gui.add_slider("Preview frame", 0, 1, 1, 0, disabled=True)
        self.prev_info = gui.add_markdown("")
        self.btn_play.on_click(lambda e: self.play())
        self.btn_pause.on_click(lambda e: self.pause())
        self.prev_plan.on_update(lambda e: self.load(force=True))
        self.slider.on_update(lambda e: self.show_frame(int(self.slider.value)))

    def load(self, force: bool = False) -> None:
        """The chosen plan's preview from its first frame; the same plan again (it gained the worlds a
        risky step is shown in) keeps its place and keeps playing."""
        with self.lock:
            got = self.source(self.prev_plan.value)
            preview, plan = got[0], got[1]
            shown = got[2] if len(got) > 2 else {}
            key = (self.prev_plan.value, plan.content_hash() if plan is not None else None, len(preview))
            same, self.loaded = key == self.loaded and not force, key
            if not same:
                self.playing = False
            n_worlds = _worlds_of(plan)
            self.frames = sv.timeline(preview, shown=shown, worlds=n_worlds) if preview else []
            self.recorded = {b for k in self.frames for b in k.poses}   # a box no frame has stays as seen
            self.risk = sv.risky_boxes(plan) if plan is not None else set()
            n = len(self.frames)
            self.slider.max = max(1, n - 1)
            self.slider.disabled = n == 0
            if same and n:
                self.show_frame(min(int(self.slider.value), n - 1))
            elif self.slider.value != 0:
                self.slider.value = 0          # triggers show_frame(0)
            elif n:
                self.show_frame(0)
            if not n:
                self.prev_info.content = self.why_none()
                scene = self.scene()
                if scene is not None:
                    sv.reset_boxes(self.drawing.client, self.drawing.nodes, scene, self.drawing.hidden)
                self.drawing.say(None)
            self.after_load()

    def show_plans(self, plans: Mapping[str, Any] | None) -> None:
        """Offer the plans there are (the physics and heuristic plans, or `continue` while held)."""
        names = tuple(n for n in (*PLANNERS, "continue") if n in (plans or {})) or PLANNERS
        if tuple(self.prev_plan.options) != names:
            self.prev_plan.options = names

    def follow(self, name: str) -> None:
        """Show the plan the supervisor is deciding on (this browser's 3D view follows its choice)."""
        if name in self.prev_plan.options and self.prev_plan.value != name:
            self.prev_plan.value = name       # loads it (on_update)

    def show_frame(self, i: int) -> None:
        with self.lock:
            if not self.frames or not self.drawing.nodes:
                return
            i = max(0, min(i, len(self.frames) - 1))
            fr = self.frames[i]
            scene = self.scene()
            sv.apply_keyframe(self.drawing.client, self.drawing.nodes, fr, scene.shelf, None, self.recorded)
            nsteps = max(k.step for k in self.frames) + 1
            txt = f"Step {fr.step + 1}/{nsteps}: pulling **{md(fr.box)}** · t = {fr.t:.2f} s"
            if fr.world:
                txt += f" · {fr.world}"
            if fr.collapsed:
                txt += f" · **collapsed: {', '.join(md(b) for b in fr.collapsed)}**"
            self.prev_info.content = txt
            self.drawing.say(preview_caption(self.prev_plan.value, fr, nsteps))

    def play(self) -> None:
        """Play from the slider's frame at the recorded pace (simulated seconds = wall seconds)."""
        with self.lock:
            if self.playing or not self.frames:
                return
            self.playing = True
            if int(self.slider.value) >= len(self.frames) - 1:
                self.slider.value = 0
            start = time.monotonic() - self.frames[int(self.slider.value)].t

        def run() -> None:
            while True:
                with self.lock:
                    if not self.playing:
                        return
                    i = sv.frame_at(self.frames, time.monotonic() - start)
                    if i != int(self.slider.value):
                        self.slider.value = i
                    if i >= len(self.frames) - 1:
                        self.playing = False
                        return
                time.sleep(1 / 30)

        threading.Thread(target=run, name="shelfpick-preview", daemon=True).start()

    def pause(self) -> None:
        with self.lock:
            self.playing = False

    def show_shelf(self) -> None:
        """Stop playing and draw the shelf again, not a predicted frame (a run started: the robot is
        taking boxes out of the real shelf, which the view then follows look by look)."""
        with self.lock:
            self.playing = False
            scene = self.scene()
            if scene is not None:
                sv.reset_boxes(self.drawing.client, self.drawing.nodes, scene, self.drawing.hidden)
            self.drawing.say(None)


class OperatorPanel:
    """The `Operator` tab: capture, target, plan, the preview player, stop, robot progress, camera images."""

    def __init__(self, gui: viser.GuiApi, wf: Workflow, do: Do,
                 make_preview: Callable[[viser.GuiApi], PreviewPlayer]) -> None:
        g = gui
        self.wf = wf
        self.status = g.add_markdown("Starting…")
        self.btn_capture = g.add_button("Capture", icon="camera")
        self.target = g.add_dropdown("Target", ("—",), initial_value="—")
        self.btn_extract = g.add_button("Plan extraction", color="blue")
        self.btn_clear = g.add_button("Plan clearance")
        self.answers = AnswerLine(g, wf)      # what became of the last click here, or of a run since
        self.answer = self.answers.handle
        self.progress = g.add_progress_bar(0.0, visible=False, animated=True)
        self.results = g.add_markdown("")
        with g.add_folder("Preview"):
            self.preview = make_preview(g)
        self.btn_stop = g.add_button("Stop robot", color="red", icon="hand-stop")
        self.robot_md = g.add_markdown("")
        self.deviation_md = g.add_markdown("")
        with g.add_folder("Camera"):
            self.img_rgb = g.add_image(PLACEHOLDER, label="RGB")
            self.img_overlay = g.add_image(PLACEHOLDER, label="Segmentation")

        self.do = do
        self.actions: dict[str, tuple[Callable[..., Any], tuple]] = {
            "Capture": (wf.capture, ()), "Plan extraction": (wf.plan, ("extract",)),
            "Plan clearance": (wf.plan, ("clear",)), "Stop robot": (wf.stop, ("operator",))}
        for btn, what in ((self.btn_capture, "Capture"), (self.btn_extract, "Plan extraction"),
                          (self.btn_clear, "Plan clearance"), (self.btn_stop, "Stop robot")):
            btn.on_click(lambda e, what=what: self.press(e, what))

        @self.target.on_update
        def _(event: Any) -> None:
            if event.client is None:      # our own programmatic update
                return
            v = self.target.value
            if v != "—" and v != wf.state.target:
                do(event, wf.select_target, v)

    def press(self, event: Any, what: str) -> None:
        """What a click on the button named `what` does (its answer in the answer line)."""
        fn, args = self.actions[what]
        self.do(event, self.answers.clicked(what, fn, *args))

    def show_images(self, rgb: np.ndarray | None, overlay: np.ndarray | None) -> None:
        """The camera folder; rgb None keeps the image shown, overlay None shows the placeholder."""
        if rgb is not None:
            self.img_rgb.image = rgb
        self.img_overlay.image = overlay if overlay is not None else PLACEHOLDER

    def show_targets(self, scene: Scene | None) -> None:
        self.target.options = tuple(scene.ids) if scene is not None and scene.boxes else ("—",)

    def follow_target(self, target: str | None) -> None:
        want = target or "—"
        if self.target.value != want and want in self.target.options:
            self.target.value = want


# clicks whose work is over when the call returns (a rejection is recorded then); the others
# start something that goes on: a plan being computed, a run
DONE_WHEN_RETURNED = frozenset({"Capture", "Stop robot", "Reject"})
DONE_WHEN_PLANNED = frozenset({"Plan extraction", "Plan clearance"})   # started, then done when the plans are in


class AnswerLine:
    """A panel's answer line: what became of its last click, or of a run that ended since.

    A click is never silent: its answer (`…`, done, started, not done: a refusal says why) stays
    until the next click, whatever the status line says meanwhile; the error still goes on to the
    browser's notification. A run that ends after the click began takes its place ("Run: held
    at b3 after step 3 of 5."), so an answer like "Plan clearance: started." never outlives a
    later run's end, and stays the line's answer until the next click or run end."""

    def __init__(self, gui: viser.GuiApi, wf: Workflow) -> None:
        self.handle = gui.add_markdown("")
        self.wf = wf
        self.lock = threading.Lock()
        self.text = ""
        self.since: RunEnd | None = None     # the run end the answer already accounts for
        self.closed = False                  # the browser went away: a click's late answer is not sent
        self.replayed: int | None = None     # the stored session this browser replays, if it does
        self.planning: str | None = None     # a planning click answered "started" whose plans are not in yet

    def close(self) -> None:
        with self.lock:
            self.closed = True

    def clicked(self, what: str, fn: Callable[..., Any], *args: Any) -> Callable[[], None]:
        """`fn(*args)` with its answer in this line."""
        def go() -> None:
            self._say(f"_{what}: …_", fresh=True)
            try:
                fn(*args)
            except Exception as exc:
                self._say(f"**{what}: not done.** {ours(exc)}")
                raise
            self._say(f"_{what}: done._" if what in DONE_WHEN_RETURNED else f"_{what}: started._",
                      planning=what if what in DONE_WHEN_PLANNED else None)
        return go

    def _say(self, text: str, fresh: bool = False, planning: str | None = None) -> None:
        with self.lock:
            if fresh:                        # a run that ended before this click is not its answer
                self.since = self.wf.state.run_end
            self.text = text
            self.planning = planning
        self.show(self.wf.state)

    def replays(self, session: int | None) -> None:
        """This browser replays stored `session` (None: it is live again). The answer stays the live
        console's (a "Stop robot" click still gets one), and says so: above a replayed session's
        plans and robot, "Run: stopped at step 3" would read as how that session ended."""
        with self.lock:
            self.replayed = session

    def _newest(self, state: State) -> State:
        """`state`, or the workflow's own when that is newer: renders run on viser's thread pool and
        may arrive out of order, and a planning click's "started." must not outlive its plans
        because the last render to arrive was of a state from before they came in."""
        live = self.wf.state
        return live if live.version > state.version else state

    def show(self, state: State) -> None:
        """The answer as of `state`: a run end the click did not know of replaces it."""
        with self.lock:
            if self.closed:
                return
            end = state.run_end
            if end is not None and end is not self.since:
                self.since, self.text, self.planning = end, run_end_answer(end), None
            elif self.planning is not None and not (now := self._newest(state)).planning:
                # "Plan extraction: started." stayed above the plans it had started
                n = len(now.plans)
                self.text = (f"_{self.planning}: done, {n} plan{'s' if n != 1 else ''}._" if n
                             else f"**{self.planning}: no plans.** {md(now.error or now.message or '')}".rstrip())
                self.planning = None
            text = self.text
            if text and self.replayed is not None:
                text = f"_Live console, not the replayed session {md(self.replayed)}:_ {text}"
            if self.handle.content != text:
                self.handle.content = text


def run_end_words(end: RunEnd) -> str:
    """How a run ended, in a few words (markdown, outside text escaped): "done, 5 of 5 steps",
    "held at b3 after step 3 of 5", "failed at step 2 of 5 (b4), 1 of 5 steps done"."""
    n, k = len(end.sequence), len(end.completed)
    at = f" at step {end.step + 1} of {n} ({md(end.box)})" if end.step is not None else ""
    if end.status == "done":
        return f"done, {k} of {n} steps"
    if end.status == "held":
        return (f"held at {md(end.box)} after step {end.step + 1} of {n}" if end.step is not None
                else f"held, {k} of {n} steps done")
    if end.status == "stopped":
        by = f" by {md(end.stopped_by)}" if end.stopped_by else ""
        return f"stopped{by}{at}, {k} of {n} steps done"
    return f"{md(end.status)}{at}, {k} of {n} steps done"


def run_end_answer(end: RunEnd) -> str:
    """The answer line once a run has ended."""
    words = f"Run: {run_end_words(end)}."
    return f"_{words}_" if end.status == "done" else f"**{words}**"


def executed_markdown(end: RunEnd) -> str:
    """The plan a run executed and how it ended: said in place of the plan, which is no longer up
    for review (its approval was used up by the run)."""
    seq = " → ".join(md(b) for b in end.sequence) or "—"
    return (f"**Executed:** the **{md(end.planner)}** plan `{md(end.plan)}` ({seq}): "
            f"**{run_end_words(end)}**.")


_UUID = re.compile(r"[0-9a-f]{8}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{4}-[0-9a-f]{12}")


def hide_typed(gui: viser.GuiApi, field: Any) -> Any:
    """Show what is typed into a text field as dots, as a password field does: viser has no such
    field, so a style rule masks the input in the row whose label points at the field's id (the
    only handle on it a page has). A supervisor's passphrase is not left on the screen for
    whoever stands behind them. Returns the style's handle."""
    uuid = field._impl.uuid        # viser's id of the field: its label's `for` in the page
    if not _UUID.fullmatch(uuid):
        raise ValueError(f"viser field id {uuid!r} is not a uuid: the style rule would not be safe to write")
    row = f'.mantine-Flex-root:has(> div > p > label[for="{uuid}"])'
    return gui.add_html(f"<style>{row} input {{ -webkit-text-security: disc; }}</style>")


class SupervisorPanel:
    """The `Supervisor` tab: the pending plans, approve (and run) or reject with a passphrase."""

    def __init__(self, gui: viser.GuiApi, wf: Workflow, do: Do, client_key: Callable[[], str]) -> None:
        g = gui
        self.wf = wf
        self.do = do
        self.client_key = client_key      # who is asking, for the passphrase throttle
        self.sup_info = g.add_markdown("")
        self.who = g.add_text("Name", "supervisor")
        self.passphrase = g.add_text("Passphrase", "")
        self.passphrase_mask = hide_typed(g, self.passphrase)
        self.approve_plan = g.add_dropdown("Plan", PLANNERS + ("continue",), initial_value=PLANNERS[0])
        self.accept_risk = g.add_checkbox("Accept predicted risk", False,
                                          hint="needed to approve a plan predicted unsafe")
        self.btn_approve = g.add_button("Approve", color="green")
        self.reason = g.add_text("Reject reason", "")
        self.btn_reject = g.add_button("Reject", color="orange")
        self.answers = AnswerLine(g, wf)      # what became of the last Approve / Reject, or its run
        self.answer = self.answers.handle
        self.decisions_md = g.add_markdown("")
        self.btn_approve.on_click(self.approve)
        self.btn_reject.on_click(self.reject)
        # the plan under review in this browser, (planner, hash) as shown here: Approve and Reject
        # send exactly it; changing it clears every acknowledgement (passphrase, risk tick)
        self.reviewed: tuple[str, str] | None = None
        self.ack_lock = threading.Lock()
        self.approve_plan.on_update(lambda e: self.review(self.wf.state))

    def render(self, state: State) -> None:
        self.show_plans(state)
        self.review(state)
        self.answers.show(state)
        self.decisions_md.content = decisions_table(state.decisions) or "_No decisions for this capture._"

    def review(self, state: State) -> None:
        """Show the plan under review (the `Plan` choice: planner, hash, sequence) and remember it.

        The pair shown is the pair decided on; when it changes (a re-plan, another target,
        another choice) the passphrase and the risk tick are cleared, so no acknowledgement
        given for one plan carries over to a plan the supervisor has not looked at."""
        name = self.approve_plan.value
        entry = (state.plans or {}).get(name)
        now = (name, entry.hash) if entry is not None else None
        with self.ack_lock:
            if now != self.reviewed:
                self.reviewed = now
                self.passphrase.value = ""
                self.accept_risk.value = False
            self.sup_info.content = supervisor_markdown(state) + review_markdown(name, entry)

    def show_plans(self, state: State) -> None:
        """The `Plan` dropdown offers exactly the plans there are to decide on: `continue` only while
        a run is held, nothing while there are none; a choice that went away moves to what is left."""
        open_plans = {} if state.needs_recapture else (state.plans or {})   # after a run: nothing to decide
        names = tuple(n for n in (*PLANNERS, "continue") if n in open_plans) or ("—",)
        if tuple(self.approve_plan.options) != names:
            keep = self.approve_plan.value
            self.approve_plan.options = names
            if keep in names and self.approve_plan.value != keep:
                self.approve_plan.value = keep

    def _entry_for_approval(self) -> PlanEntry:
        entry = self.wf.state.plans.get(self.approve_plan.value)
        if entry is None:
            raise WorkflowError("no plan to decide on: plan first")
        return entry

    def _risk_unticked(self, entry: PlanEntry) -> str | None:
        """Why this approval needs `Accept predicted risk` ticked, when it is not: said before the
        passphrase is taken, so a missing tick costs no retyping (the workflow checks it again)."""
        if self.accept_risk.value:
            return None
        if (entry.plan.extra or {}).get("continues"):
            return "continuing a held plan needs 'Accept predicted risk' ticked"
        if not entry.plan.safe or entry.scene_problems:
            return (f"the {entry.plan.planner} plan is predicted unsafe: tick 'Accept predicted risk' to "
                    f"approve it anyway")
        return None

    def _take_passphrase(self) -> str:
        """The typed passphrase, and the field cleared at once: every use needs it typed again."""
        given = self.passphrase.value
        self.passphrase.value = ""
        return given

    def _acknowledged(self, check_tick: bool) -> tuple[tuple[str, str], str, bool]:
        """(plan under review, passphrase, risk tick), taken together under the lock `review` clears
        them under: a decision never pairs one plan's acknowledgements with another plan."""
        with self.ack_lock:
            reviewed = self.reviewed
            if reviewed is None:
                self._take_passphrase()
                raise WorkflowError("no plan to decide on: plan first")
            entry = self.wf.state.plans.get(reviewed[0])
            unticked = self._risk_unticked(entry) if check_tick and entry is not None \
                and entry.hash == reviewed[1] else None
            if unticked is not None:          # refused before the passphrase is used: it stays typed
                raise WorkflowError(f"approval refused: {unticked}")
            given, accept = self._take_passphrase(), bool(self.accept_risk.value)
        if not given:
            raise WorkflowError("type the supervisor passphrase first (it is cleared after every use and "
                                "whenever the plan under review changes)")
        return reviewed, given, accept

    def approve(self, event: Any) -> None:
        def go() -> None:
            (name, plan_hash), given, accept = self._acknowledged(check_tick=True)
            self.wf.approve(plan_hash, given, self.who.value.strip() or "supervisor",
                            accept_risk=accept, client=self.client_key(), planner=name)
            self.accept_risk.value = False
            self.wf.execute()
        self.do(event, self.answers.clicked("Approve", go))

    def reject(self, event: Any) -> None:
        def go() -> None:
            if not self.reason.value.strip():
                self._take_passphrase()
                raise WorkflowError("Reject needs a reason: type it in `Reject reason`")
            (name, plan_hash), given, _ = self._acknowledged(check_tick=False)
            self.wf.reject(plan_hash, given, self.who.value.strip() or "supervisor",
                           self.reason.value, client=self.client_key(), planner=name)
            self.reason.value = ""
        self.do(event, self.answers.clicked("Reject", go))


def supervisor_markdown(state: State) -> str:
    """The pending plans of the current capture, as the supervisor decides on them; after a run, the
    plan it ran is not pending: the run used its approval up."""
    end = state.run_end
    if state.needs_recapture:
        ran = f"{executed_markdown(end)}\n\n" if end is not None else ""
        return ran + "_Nothing to decide: the robot ran; capture and plan again before the next run._"
    if not state.plans:
        return "_Nothing to decide: no plans for the current capture._"
    lines = [executed_markdown(end) + "\n"] if end is not None else []
    lines.append("Pending plans for this capture:")
    for name, e in state.plans.items():
        mark = " ✅ approved" if state.approved == e.hash else rejected_mark(state.decisions, name, e.hash)
        lines.append(f"- **{md(name)}** `{md(e.hash)}`: {' → '.join(md(b) for b in e.plan.sequence)} "
                     f"({risk_words(e.plan)}{'' if e.plan.safe else ', predicted UNSAFE'}){mark}"
                     + "".join(f"\n  - {w}" for w in why_unsafe(e.plan)))
    if state.scene_problems:
        lines.append("\n**⚠ The shelf does not stand as seen:** " + "; ".join(
            md(problem_text(p)) for p in state.scene_problems)
            + ". Approving needs “Accept predicted risk”.")
    lines.append("\n“Approve” sends the chosen plan to the robot at once.")
    return "\n".join(lines)


def rejected_mark(decisions: Iterable[Mapping[str, Any]], planner: str, plan_hash: str) -> str:
    """" ❌ rejected by X" for a plan of this capture a supervisor rejected ('' if none did): listed
    as pending like a plan nobody decided on, it read as still waiting for a decision."""
    who = [d.get("who") for d in decisions if d.get("decision") == "reject" and d.get("plan") == plan_hash
           and d.get("planner", planner) == planner]
    return f" ❌ rejected by {md(who[-1])}" if who else ""


def touched(plan: Plan, key: str = "unexplained") -> list[str] | None:
    """Why the plan touches unexplained matter (planning/unexplained.py), or with `key`
    "contradicted" a face perception doubts (planning/contradicted.py), one sentence a step; []
    when it does not, None when its scene had none."""
    doc = (plan.extra or {}).get(key)
    if not isinstance(doc, dict):
        return None
    return [str(t) for t in doc.get("touched") or [] if isinstance(t, str)]


def why_unsafe(plan: Plan) -> list[str]:
    """Why the planner did not call `plan` safe, as the supervisor should read before accepting
    the risk: the calibrated chance against the cell's threshold, and the steps that touch a face
    perception doubts or matter it cannot explain (the reasons the plan JSON records). [] for a
    safe plan."""
    if plan.safe:
        return []
    out: list[str] = []
    risk = plan_risk(plan)
    if risk is not None:
        _, _, hi, limit = risk
        if hi >= limit:
            out.append(f"calibrated chance of a collapse up to {100 * hi:.1f}%, not below the "
                       f"threshold {100 * limit:.1f}%")
    for key in ("contradicted", "unexplained"):
        out += [md(t) for t in touched(plan, key) or ()]
    return out


def review_markdown(name: str, entry: PlanEntry | None) -> str:
    """The plan `Approve` and `Reject` decide on in this browser: planner, hash and sequence."""
    if entry is None:
        return ""
    return (f"\n\n**Deciding on:** the **{md(name)}** plan `{md(entry.hash)}`: "
            f"{' → '.join(md(b) for b in entry.plan.sequence)} ({risk_words(entry.plan)}"
            f"{'' if entry.plan.safe else ', predicted UNSAFE'})"
            + "".join(f"\n- {w}" for w in why_unsafe(entry.plan)))


def decisions_table(decisions: Iterable[Mapping[str, Any]]) -> str:
    """The supervisors' decisions on this capture, one row each, naming the planner whose plan it
    was (two planners can find one sequence, one hash); names and reasons are outside text."""
    rows = [f"| {md(d.get('decision'))} | {md(d.get('planner') or '—')} | `{md(d.get('plan'))}` | "
            f"{md(d.get('who'))} | {md(_fmt_clock(d.get('at')))} | {md(d.get('reason') or '')} |"
            for d in decisions]
    if not rows:
        return ""
    return "\n".join(["| decision | planner | plan | by | at | reason |", "|---|---|---|---|---|---|", *rows])


def decisions_markdown(decisions: Iterable[Mapping[str, Any]], key: str = "plan") -> str:
    """Supervisors' decisions; names and reasons are outside text."""
    return "\n".join(
        f"- {md(d['decision'])} `{md(d.get(key))}` by {md(d.get('who'))}"
        + (f" at {md(start_time_words(d['at']))}" if isinstance(d.get("at"), str) else "")
        + (f" (the **{md(d['planner'])}** plan)" if d.get("planner") else "")
        + (f": {md(d['reason'])}" if d.get("reason") else "")
        for d in decisions)


class SessionsPanel:
    """The `Sessions` tab: the stored sessions, replay of one, and its looks after each step."""

    def __init__(self, gui: viser.GuiApi, wf: Workflow) -> None:
        g = gui
        self.wf = wf
        self.last_sessions_key: tuple | None = None
        self.look_nodes: list[viser.SceneNodeHandle] = []
        self.sessions_md = g.add_markdown("")
        self.session_pick = g.add_dropdown("Session", ("—",), initial_value="—")
        self.btn_replay = g.add_button("Replay")
        self.look_pick = g.add_dropdown("Look after step", ("—",), initial_value="—",
                                        hint="replay: the observed shelf after a step, the predicted "
                                             "poses as blue outlines, what differs in red")
        self.btn_live = g.add_button("Back to live")
        self.btn_export = g.add_button("Export HTML", icon="download",
                                       hint="the chosen session as one self-contained web page (downloads)")
        self.replay_md = g.add_markdown("")
        self.look_md = g.add_markdown("")
        with g.add_folder("Session images"):
            self.img_rgb = g.add_image(PLACEHOLDER, label="Captured")
            self.img_overlay = g.add_image(PLACEHOLDER, label="Segmentation")
        self.picked = False               # the person chose a session: keep it, else follow the newest
        self.session_pick.on_update(self._picked)

    def _picked(self, event: Any) -> None:
        if getattr(event, "client", None) is not None:
            self.picked = True

    def render(self, state: State) -> None:
        """The sessions table again when the current session changed in a way it shows."""
        key = (state.session_id, state.robot, len(state.decisions), state.plans is not None and len(state.plans))
        if key != self.last_sessions_key:
            self.last_sessions_key = key
            self.refresh()

    def refresh(self) -> None:
        try:
            rows = self.wf.store.list_sessions()
        except Exception as exc:  # noqa: BLE001 - DB locked/unreadable
            self.sessions_md.content = f"**⚠ database: {md(exc)}**"
            return
        rows = sorted(rows, key=lambda r: -int(r["id"]))
        lines = ["| id | started | source | boxes | task | status |", "|---|---|---|---|---|---|"]
        for r in rows[:12]:
            lines.append(f"| {md(r['id'])} | {md(start_time_words(r.get('started')))} | {md(r.get('source', ''))} | "
                         f"{md(r.get('n_boxes', ''))} | {md(r.get('task') or '')} | {md(r.get('status') or '')} |")
        self.sessions_md.content = "\n".join(lines) if rows else "_No sessions yet._"
        opts = tuple(str(r["id"]) for r in rows) or ("—",)     # newest first
        cur = self.session_pick.value
        self.session_pick.options = opts
        self.session_pick.value = cur if self.picked and cur in opts else opts[0]

    def start_replay(self, summary_md: str, look_labels: Sequence[str], rgb: np.ndarray | None = None,
                     overlay: np.ndarray | None = None) -> None:
        """A stored session's summary, its images, and its looks after each step to pick from."""
        self.replay_md.content = summary_md
        self.img_rgb.image = rgb if rgb is not None else PLACEHOLDER
        self.img_overlay.image = overlay if overlay is not None else PLACEHOLDER
        self.clear_look()
        self.look_pick.options = ("—",) + tuple(look_labels)
        self.look_pick.value = "—"

    def end_replay(self) -> None:
        self.replay_md.content = ""
        self.img_rgb.image = PLACEHOLDER
        self.img_overlay.image = PLACEHOLDER
        self.clear_look()
        self.look_pick.options = ("—",)
        self.look_pick.value = "—"

    def export(self, client: Any) -> str:
        """The chosen session as a self-contained HTML page, sent to this browser as a download."""
        from shelfpick.console.web.replay import render_html

        v = self.session_pick.value
        if v == "—":
            raise WorkflowError("no session to export")
        page = render_html(self.wf.store.load_session(int(v)))
        name = f"shelfpick-session-{int(v)}.html"
        client.send_file_download(name, page.encode("utf-8"), save_immediately=True)
        return name

    def clear_look(self) -> None:
        for h in self.look_nodes:
            h.remove()
        self.look_nodes = []
        self.look_md.content = ""

    def show_look(self, scene_api: viser.SceneApi, predicted: Scene | None, table_md: str) -> None:
        """A look's predicted poses as outlines and its table (the observed shelf is drawn by the view)."""
        if predicted is not None:
            self.look_nodes = sv.draw_outlines(scene_api, predicted.boxes, prefix="/look")
        self.look_md.content = table_md


def _fmt_clock(t: float | str | None) -> str:
    """A decision's time of day (the decisions are of the current capture)."""
    if isinstance(t, (int, float)) and not isinstance(t, bool):
        return time.strftime("%H:%M:%S", time.localtime(t))
    return str(t or "")
