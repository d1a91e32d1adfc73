"""The operator console's state machine: capture -> plan -> approve/reject -> execute -> stop.

The viser app is a thin view over this object. viser runs callbacks on a
thread pool, so two browsers can press buttons at the same moment: every
state change happens under one lock, and the slow parts (planning, the robot)
run on background threads that re-check, when they finish, that the capture
they worked on is still the current one. Every decision and every robot event
goes to the session store; a store failure (locked or read-only database)
becomes a message in the state, never a dead server.

Safety rules kept here, not in the page:
- only the exact plan (content hash) approved for the exact current capture
  reaches the robot; a new capture invalidates pending approvals;
- approving and rejecting need the supervisor passphrase; a wrong one is
  refused and recorded;
- after the robot ran (completed, stopped, failed or disconnected) the shelf
  has changed: a new capture and plan are needed before anything else runs.
"""
from __future__ import annotations

import hmac
import threading
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import Any, Callable, Mapping

PLANNERS = ("physics", "heuristic")
SECONDS_PER_BOX = 12.5  # estimated robot time per removed box (pull, place, return)


class WorkflowError(Exception):
    """An action that is not allowed now; the message is shown to the user as is."""


@dataclass(frozen=True, eq=False)
class PlanEntry:
    """One planner's result for the current capture."""

    plan: Any                      # planning.plan.Plan
    hash: str
    preview: tuple = ()            # StepResult list from Predictor.preview (recorded frames)

    @property
    def est_seconds(self) -> float:
        return SECONDS_PER_BOX * len(self.plan.sequence)


@dataclass(frozen=True, eq=False)
class State:
    """A snapshot of the console, handed to listeners; never mutated."""

    version: int = 0
    source: str = ""
    session_id: int | None = None
    frame_name: str = ""
    capture: Any = None            # perception.capture.Capture
    overlay: Any = None            # HxWx3 uint8 segmentation overlay
    scene: Any = None              # perceived Scene
    truth: Any = None              # true Scene when the source knows it (demo)
    warnings: tuple[str, ...] = ()
    target: str | None = None
    task: str | None = None
    plans: Mapping[str, PlanEntry] = field(default_factory=dict)
    planning: bool = False
    progress: float = 0.0
    progress_text: str = ""
    approved: str | None = None    # hash of the approved plan for this capture
    decisions: tuple[dict, ...] = ()
    robot: str = "idle"            # idle | running | stopping | done | stopped | failed
    robot_events: tuple[Any, ...] = ()
    outcome: Any = None            # console.robot.RobotOutcome
    needs_recapture: bool = False
    message: str = ""
    error: str | None = None

    def plan_by_hash(self, plan_hash: str) -> PlanEntry | None:
        for e in self.plans.values():
            if e.hash == plan_hash:
                return e
        return None


RobotFactory = Callable[[Any, int], Any]   # (truth Scene | None, seed) -> RobotDriver
Listener = Callable[[State], None]


class Workflow:
    """Thread-safe console state; the app calls these methods from any thread."""

    def __init__(self, source: Any, store: Any, robot_factory: RobotFactory,
                 supervisor_passphrase: str, samples: int = 10, seed: int = 0,
                 segmenter: Any = None, workers: int = 1) -> None:
        if not supervisor_passphrase:
            raise ValueError("a supervisor passphrase is required")
        self.source = source
        self.store = store
        self.robot_factory = robot_factory
        self._passphrase = supervisor_passphrase
        self.samples = int(samples)
        self.seed = int(seed)
        self.segmenter = segmenter
        self.workers = max(1, int(workers))     # processes for the depth samples (same plans for any count)
        self._lock = threading.RLock()
        self._state = State(source=getattr(source, "name", str(source)))
        self._listeners: list[Listener] = []
        self._generation = 0                # bumped by every capture
        self._plan_thread: threading.Thread | None = None
        self._robot_thread: threading.Thread | None = None
        self._stop = threading.Event()
        # listeners run on one notifier thread, never under the lock: a view that holds its own
        # lock and reads `state` can then never deadlock against a change being announced
        self._notify_cv = threading.Condition()
        self._pending: State | None = None
        threading.Thread(target=self._notify_loop, name="shelfpick-notify", daemon=True).start()

    # ------------------------------------------------------------------ state
    @property
    def state(self) -> State:
        with self._lock:
            return self._state

    def add_listener(self, fn: Listener) -> None:
        with self._lock:
            self._listeners.append(fn)

    def remove_listener(self, fn: Listener) -> None:
        with self._lock:
            if fn in self._listeners:
                self._listeners.remove(fn)

    def _set(self, **changes: Any) -> State:
        """Apply changes under the lock; listeners hear of it from the notifier thread."""
        with self._lock:
            self._state = replace(self._state, version=self._state.version + 1, **changes)
            snap = self._state
        with self._notify_cv:
            if self._pending is None or self._pending.version < snap.version:
                self._pending = snap
            self._notify_cv.notify()
        return snap

    def _notify_loop(self) -> None:
        """Hand the newest state to every listener, in version order (intermediate ones may be skipped)."""
        last = -1
        while True:
            with self._notify_cv:
                while self._pending is None:
                    self._notify_cv.wait()
                snap, self._pending = self._pending, None
            if snap.version <= last:
                continue
            last = snap.version
            for fn in list(self._listeners):
                try:
                    fn(snap)
                except Exception:  # noqa: BLE001 - a broken view must not break the workflow
                    traceback.print_exc()

    def _record(self, what: str, fn: Callable, *args: Any, **kw: Any) -> Any:
        """Call the store; a database fault becomes a message, the session goes on."""
        try:
            return fn(*args, **kw)
        except Exception as exc:  # noqa: BLE001 - sqlite3, OSError, ShelfpickError alike
            msg = f"database: could not record {what}: {exc}"
            with self._lock:
                self._state = replace(self._state, error=msg)
            return None

    def _refuse(self, msg: str) -> None:
        self._set(error=msg)
        raise WorkflowError(msg)

    # ---------------------------------------------------------------- capture
    def capture(self) -> State:
        """New capture -> perception -> new session. Invalidates plans and approvals."""
        with self._lock:
            if self._state.robot in ("running", "stopping"):
                self._refuse("the robot is running: press `Stop robot` or wait before capturing")
            self._generation += 1
        self._set(message="capturing...", error=None)
        try:
            frame = self.source.capture()
        except Exception as exc:  # noqa: BLE001 - camera faults are shown, not raised
            return self._capture_failed(f"camera: {exc}")
        try:
            from perception.pipeline import perceive

            shelf = frame.truth.shelf if frame.truth is not None else None  # installation geometry
            perception = perceive(frame.capture, self.segmenter, shelf=shelf)
        except Exception as exc:  # noqa: BLE001
            from perception.scene import Scene, Shelf

            shelf = frame.truth.shelf if frame.truth is not None else Shelf()
            self._record("the failed capture", self.store.new_session, self._state.source,
                         frame.capture, Scene(shelf, ()), frame.truth, None, {"error": str(exc)})
            return self._capture_failed(f"perception: {exc}", frame=frame)
        scene = perception.scene
        info = {"frame": frame.name, **_summary(perception)}
        sid = self._record("the session", self.store.new_session, self._state.source,
                           frame.capture, scene, frame.truth, perception.overlay, info)
        err = self.state.error if sid is None else None
        if not scene.boxes:
            err = "perception found no boxes in this capture: check the camera and the shelf, then capture again"
        target = scene.ids[-1] if scene.boxes else None
        return self._set(session_id=sid, frame_name=frame.name, capture=frame.capture,
                         overlay=perception.overlay, scene=scene, truth=frame.truth,
                         warnings=tuple(perception.warnings), target=target, task=None,
                         plans={}, planning=False, progress=0.0, progress_text="",
                         approved=None, decisions=(), robot="idle", robot_events=(),
                         outcome=None, needs_recapture=False, error=err,
                         message=f"captured {frame.name}: {len(scene.boxes)} boxes"
                                 + (f" (session {sid})" if sid is not None else ""))

    def _capture_failed(self, msg: str, frame: Any = None) -> State:
        return self._set(capture=frame.capture if frame else None, overlay=None, scene=None,
                         truth=None, plans={}, approved=None, decisions=(), target=None,
                         robot="idle", robot_events=(), outcome=None, planning=False,
                         session_id=None, message="", error=msg)

    # ----------------------------------------------------------------- target
    def select_target(self, box_id: str) -> State:
        with self._lock:
            scene = self._state.scene
            if scene is None:
                self._refuse("no capture yet: press `Capture` first")
            if box_id not in scene.ids:
                self._refuse(f"unknown box id {box_id!r}; the scene has {', '.join(scene.ids) or 'no boxes'}")
            if box_id == self._state.target:
                return self._state
        return self._set(target=box_id, message=f"target: {box_id}", error=None)

    # --------------------------------------------------------------- planning
    def plan(self, task: str, wait: bool = False) -> State:
        """Run both planners on the perceived scene in a background worker."""
        if task not in ("extract", "clear"):
            self._refuse(f"unknown task {task!r}; expected extract or clear")
        with self._lock:
            st = self._state
            if st.scene is None or not st.scene.boxes:
                self._refuse("nothing to plan: capture a shelf with boxes first")
            if st.needs_recapture:
                self._refuse("the shelf has changed since this capture: press `Capture` again")
            if st.planning or (self._plan_thread is not None and self._plan_thread.is_alive()):
                self._refuse("planning is already running; wait for it to finish")
            if st.robot in ("running", "stopping"):
                self._refuse("the robot is running")
            if task == "extract" and st.target is None:
                self._refuse("select a target box first")
            target = st.target if task == "extract" else None
            gen = self._generation
            scene, sid = st.scene, st.session_id
            self._plan_thread = threading.Thread(target=self._plan_worker, name="shelfpick-plan",
                                                 args=(gen, scene, sid, task, target), daemon=True)
        self._set(planning=True, task=task, plans={}, approved=None, progress=0.0,
                  progress_text="starting", error=None,
                  message=f"planning {task}" + (f" {target}" if target else "") + "...")
        self._plan_thread.start()
        if wait:
            self._plan_thread.join()
        return self.state

    def wait_planning(self, timeout: float | None = None) -> State:
        t = self._plan_thread
        if t is not None:
            t.join(timeout)
        return self.state

    def _progress(self, gen: int, frac: float, text: str) -> None:
        with self._lock:
            if gen != self._generation:
                return
        self._set(progress=frac, progress_text=text)

    def _plan_worker(self, gen: int, scene: Any, sid: int | None, task: str, target: str | None) -> None:
        predictor = None
        try:
            from planning.planner import make_plan
            from planning.predict import Predictor

            self._progress(gen, 0.05, f"building {self.samples} depth samples")
            t_setup = time.perf_counter()
            predictor = Predictor(scene, samples=self.samples, seed=self.seed, workers=self.workers)
            t_setup = time.perf_counter() - t_setup     # shared by both planners; charged to physics
            entries: dict[str, PlanEntry] = {}
            n = len(PLANNERS)
            for i, planner in enumerate(PLANNERS):
                self._progress(gen, 0.1 + 0.85 * i / n, f"{planner} planner: searching")
                t0 = time.perf_counter()
                plan = make_plan(scene, task, target, planner=planner, samples=self.samples,
                                 seed=self.seed, predictor=predictor)
                timing = dict(plan.timing)
                timing.setdefault("planning_s", time.perf_counter() - t0)
                if planner == "physics":
                    timing["setup_s"] = timing.get("setup_s", 0.0) + t_setup
                plan = replace(plan, timing=timing)
                self._progress(gen, 0.1 + 0.85 * (i + 0.6) / n, f"{planner} planner: recording preview")
                preview = tuple(predictor.preview(plan.sequence, 0)) if plan.sequence else ()
                entries[planner] = PlanEntry(plan, plan.content_hash(), preview)
            with self._lock:
                if gen != self._generation:
                    return  # a new capture arrived meanwhile: these plans are for the old shelf
            for e in entries.values():
                self._record(f"the {e.plan.planner} plan", self.store.add_plan, sid, e.plan,
                             [_step_json(r) for r in e.preview]) if sid is not None else None
            phys = entries["physics"].plan
            err = self.state.error
            if not phys.safe:
                err = (f"no safe plan: the least risky sequence still has a predicted collapse "
                       f"risk of {100 * phys.risk:.0f}%; a supervisor may approve it only by "
                       f"accepting that risk. Or rearrange the shelf and capture again")
            self._set(plans=entries, planning=False, progress=1.0, progress_text="done", error=err,
                      message="plans ready: compare them, preview, then a supervisor approves one")
        except Exception as exc:  # noqa: BLE001 - shown in the page, the server keeps running
            traceback.print_exc()
            with self._lock:
                stale = gen != self._generation
            if not stale:
                self._set(planning=False, progress=0.0, progress_text="failed",
                          error=f"planning failed: {exc}")
        finally:
            if predictor is not None:
                try:
                    predictor.close()
                except Exception:  # noqa: BLE001
                    pass
            with self._lock:
                if self._state.planning and gen != self._generation:
                    self._state = replace(self._state, planning=False)

    # ------------------------------------------------------------- supervisor
    def _check_passphrase(self, plan_hash: str, passphrase: str, who: str, action: str) -> None:
        ok = hmac.compare_digest((passphrase or "").encode(), self._passphrase.encode())
        if not ok:
            st = self.state
            if st.session_id is not None:
                # the store's decisions are approve/reject only: a refused attempt is an event
                self._record("the refused attempt", self.store.add_robot_event, st.session_id, plan_hash,
                             "auth_refused", None, None,
                             {"who": who or "?", "action": action, "reason": "wrong supervisor passphrase"})
            self._set(decisions=st.decisions + ({"decision": "refused", "plan": plan_hash, "who": who,
                                                 "reason": f"{action}: wrong passphrase",
                                                 "at": time.time()},))
            self._refuse(f"{action} refused: wrong supervisor passphrase (recorded)")

    def _current_entry(self, plan_hash: str, action: str) -> PlanEntry:
        st = self.state
        if st.planning:
            self._refuse(f"{action} refused: planning is still running")
        entry = st.plan_by_hash(plan_hash)
        if entry is None:
            self._refuse(f"{action} refused: plan {plan_hash} is not a plan for the current capture")
        return entry

    def approve(self, plan_hash: str, passphrase: str, who: str = "supervisor",
                accept_risk: bool = False) -> State:
        """Approve exactly this plan for exactly the current capture.

        A plan predicted unsafe (the least risky one when no safe plan exists)
        needs `accept_risk`: the supervisor says in so many words that they
        take the predicted risk, and the decision records it.
        """
        self._check_passphrase(plan_hash, passphrase, who, "approval")
        with self._lock:
            entry = self._current_entry(plan_hash, "approval")
            st = self._state
            if st.needs_recapture:
                self._refuse("approval refused: the shelf has changed, capture and plan again")
            if st.robot in ("running", "stopping"):
                self._refuse("approval refused: the robot is running")
            risk_note = None
            if not entry.plan.safe:
                risk = f"{100 * entry.plan.risk:.0f}%"
                if not accept_risk:
                    self._refuse(f"approval refused: the {entry.plan.planner} plan is predicted unsafe "
                                 f"(collapse risk up to {risk}); tick 'Accept predicted risk' to approve it anyway")
                risk_note = f"accepted predicted risk {risk}"
            sid = st.session_id
        if sid is not None:
            self._record("the approval", self.store.add_decision, sid, plan_hash, "approve", who, risk_note)
        with self._lock:
            if self._state.plan_by_hash(plan_hash) is None:   # a capture raced us
                self._refuse("approval refused: a new capture arrived")
            dec = {"decision": "approve", "plan": plan_hash, "planner": entry.plan.planner,
                   "who": who, "reason": risk_note, "at": time.time()}
            return self._set(approved=plan_hash, decisions=self._state.decisions + (dec,), error=None,
                             message=f"{who} approved the {entry.plan.planner} plan {plan_hash}")

    def reject(self, plan_hash: str, passphrase: str, who: str = "supervisor", reason: str = "") -> State:
        if not (reason or "").strip():
            self._refuse("reject needs a reason")
        self._check_passphrase(plan_hash, passphrase, who, "rejection")
        with self._lock:
            entry = self._current_entry(plan_hash, "rejection")
            sid = self._state.session_id
        if sid is not None:
            self._record("the rejection", self.store.add_decision, sid, plan_hash, "reject", who, reason.strip())
        with self._lock:
            dec = {"decision": "reject", "plan": plan_hash, "planner": entry.plan.planner,
                   "who": who, "reason": reason.strip(), "at": time.time()}
            approved = None if self._state.approved == plan_hash else self._state.approved
            return self._set(approved=approved, decisions=self._state.decisions + (dec,), error=None,
                             message=f"{who} rejected the {entry.plan.planner} plan: {reason.strip()}")

    # ------------------------------------------------------------------ robot
    def execute(self, wait: bool = False) -> State:
        """Send the approved plan to the robot on a background thread."""
        with self._lock:
            st = self._state
            if st.approved is None:
                self._refuse("nothing approved: a supervisor must approve a plan first")
            entry = st.plan_by_hash(st.approved)
            if entry is None:
                self._refuse("the approved plan is not for the current capture")
            if st.robot in ("running", "stopping"):
                self._refuse("the robot is already running")
            if st.needs_recapture:
                self._refuse("the shelf has changed: capture and plan again")
            self._stop = threading.Event()
            gen, sid, scene, truth = self._generation, st.session_id, st.scene, st.truth
            self._robot_thread = threading.Thread(target=self._robot_worker, name="shelfpick-robot",
                                                  args=(gen, sid, entry, scene, truth, self._stop),
                                                  daemon=True)
            # the approval is used up: re-running would re-send completed steps
            self._state = replace(self._state, approved=None)
        self._set(robot="running", robot_events=(), outcome=None, error=None,
                  message=f"robot: executing the {entry.plan.planner} plan {entry.hash}")
        self._robot_thread.start()
        if wait:
            self._robot_thread.join()
        return self.state

    def wait_robot(self, timeout: float | None = None) -> State:
        t = self._robot_thread
        if t is not None:
            t.join(timeout)
        return self.state

    def stop(self, who: str = "operator") -> State:
        """Abort the remaining steps at once (the driver checks the event between and within steps)."""
        with self._lock:
            running = self._state.robot == "running"
            self._stop.set()
        if not running:
            return self._set(message="robot is not running")
        return self._set(robot="stopping", message=f"{who} pressed Stop robot: aborting remaining steps")

    def _robot_worker(self, gen: int, sid: int | None, entry: PlanEntry, scene: Any, truth: Any,
                      stop: threading.Event) -> None:
        h = entry.hash

        def on_event(ev: Any) -> None:
            if sid is not None:
                self._record("a robot event", self.store.add_robot_event, sid, h, ev.kind,
                             ev.step, ev.box, dict(ev.detail) if ev.detail else None)
            with self._lock:
                events = self._state.robot_events + (ev,)
            self._set(robot_events=events, message=f"robot: {ev.kind}"
                      + (f" step {ev.step + 1 if isinstance(ev.step, int) else ev.step}" if ev.step is not None else "")
                      + (f" ({ev.box})" if ev.box else ""))

        try:
            robot = self.robot_factory(truth, self.seed)
            if sid is not None:
                self._record("the robot start", self.store.add_robot_event, sid, h, "start", None, None,
                             {"robot": getattr(robot, "name", "?"), "sequence": list(entry.plan.sequence)})
            outcome = robot.execute(entry.plan, scene, on_event, stop)
        except Exception as exc:  # noqa: BLE001 - robot refused / unreachable
            traceback.print_exc()
            outcome = None
            err = f"robot: {exc}"
        else:
            err = None if outcome.ok else f"robot: {outcome.error or 'the plan did not succeed'}"
        out_doc = _outcome_json(outcome, err, entry, stop.is_set())
        if sid is not None:
            self._record("the outcome", self.store.set_outcome, sid, out_doc)
        if stop.is_set() and (outcome is None or not outcome.ok):
            status, msg = "stopped", "robot stopped"
        elif outcome is not None and outcome.ok:
            status, msg = "done", "robot finished the plan"
        else:
            status, msg = "failed", "robot stopped on an error"
        done = ", ".join(outcome.completed) if outcome is not None and outcome.completed else "none"
        msg += f"; completed steps: {done}. Capture and plan again before the next run."
        self._set(robot=status, outcome=outcome, needs_recapture=True, message=msg,
                  error=err if status != "stopped" else None)


def _summary(perception: Any) -> dict:
    try:
        return dict(perception.summary())
    except Exception:  # noqa: BLE001 - an older Perception without summary()
        return {"warnings": list(perception.warnings), "timing": dict(perception.timing)}


def _step_json(result: Any) -> dict:
    """A preview step with its recorded frames, so a replay can animate it without the server."""
    try:
        return result.to_json(frames=True)
    except TypeError:
        return result.to_json()


def _outcome_json(outcome: Any, err: str | None, entry: PlanEntry, stopped: bool) -> dict:
    doc: dict[str, Any] = {"plan": entry.hash, "planner": entry.plan.planner,
                           "sequence": list(entry.plan.sequence), "stopped": stopped}
    if outcome is not None:
        doc.update({"completed": list(outcome.completed), "ok": bool(outcome.ok), "error": outcome.error,
                    "steps": [dict(s) for s in outcome.steps]})
    else:
        doc.update({"completed": [], "ok": False, "error": err, "steps": []})
    return doc


__all__ = ["Workflow", "WorkflowError", "State", "PlanEntry", "PLANNERS", "SECONDS_PER_BOX"]
