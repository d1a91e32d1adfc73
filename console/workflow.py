"""The operator console's state machine: capture -> plan -> approve/reject -> execute -> stop.

The viser app is a thin view over this object. viser runs callbacks on a
thread pool, so two browsers can press buttons at the same moment: every
state change happens under one lock, and the slow parts (capture, planning,
the robot) run outside it, guarded by flags taken under it. docs/console.md
draws the states and transitions; tests/console/test_safety_*.py drive each.

Safety rules kept here, not in the page:
- one run lock, taken by an approval and held until its run ends (or Stop
  withdraws it): while it is held nothing captures, plans, approves again or
  changes the target, and one Stop reaches the run that holds it;
- only the exact plan (content hash) approved for the exact current capture
  (its session, one per capture) reaches the robot; a new capture or target
  drops the plans;
- audit first: an approval counts once its decision is committed, the robot
  starts once its run is committed, and a robot event that cannot be
  committed stops the run at once; the page says so until the next capture;
- approving and rejecting need the supervisor passphrase; wrong tries are
  throttled per browser and overall, and every refusal reads the same;
- "never re-send a step" is keyed by session and plan, from the database;
- after the robot ran (completed, stopped, failed or disconnected) the shelf
  has changed: a new capture and plan are needed before anything else runs.
"""
from __future__ import annotations

import hmac
import threading
import time
import traceback
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any, Callable, Mapping, NamedTuple

from perception.scene import Box, Scene, Shelf
from planning.plan import PLANNERS, Plan  # PLANNERS: the planners the console runs side by side

if TYPE_CHECKING:   # for annotations only: importing these costs numpy, cv2 or the planner
    import numpy as np

    from console.robot_types import RobotDriver, RobotEvent, RobotOutcome
    from console.sources import Frame, Source
    from console.store import SessionStore
    from console.verify import Tolerance, Verification
    from perception.capture import Capture
    from perception.pipeline import Perception
    from perception.segment import Segmenter
    from planning.bullet_clients import ClientPool
    from planning.predict import Predictor
    from planning.step_result import StepResult

    PreviewStep = StepResult | Mapping[str, Any]   # a recorded step, or its JSON (a continued plan's)

SECONDS_PER_BOX = 12.5  # estimated robot time per removed box (pull, place, return)
AUTH_REFUSED = "wrong supervisor passphrase, or too many attempts: wait a moment and try again (recorded)"


class WorkflowError(Exception):
    """An action that is not allowed now; the message is shown to the user as is."""


@dataclass(frozen=True, eq=False)
class PlanEntry:
    """One planner's result for the current capture."""

    plan: Plan
    hash: str
    preview: tuple[PreviewStep, ...] = ()   # from Predictor.preview (recorded frames)
    shelves: tuple[Scene, ...] = ()         # the perceived Scene after each step, as predicted (verification)

    @property
    def est_seconds(self) -> float:
        return SECONDS_PER_BOX * len(self.plan.sequence)

    @property
    def scene_problems(self) -> tuple[dict, ...]:
        """What the planner found does not stand as seen (plan.extra["scene_check"])."""
        return scene_problems(self.plan)


@dataclass(frozen=True, eq=False)
class State:
    """A snapshot of the console, handed to listeners; never mutated."""

    version: int = 0
    source: str = ""
    session_id: int | None = None
    frame_name: str = ""
    capture: Capture | None = None
    overlay: np.ndarray | None = None   # HxWx3 uint8 segmentation overlay
    scene: Scene | None = None          # perceived Scene
    truth: Scene | None = None          # true Scene when the source knows it (demo)
    warnings: tuple[str, ...] = ()
    target: str | None = None
    task: str | None = None
    plans: Mapping[str, PlanEntry] = field(default_factory=dict)
    capturing: bool = False
    planning: bool = False
    progress: float = 0.0
    progress_text: str = ""
    approved: str | None = None    # hash of the approved plan for this capture
    approval: Mapping[str, Any] | None = None   # plan, session, capture, who, decision id
    decisions: tuple[dict, ...] = ()
    robot: str = "idle"            # idle | running | stopping | done | stopped | failed
    robot_events: tuple[RobotEvent, ...] = ()
    outcome: RobotOutcome | None = None
    needs_recapture: bool = False
    scene_problems: tuple[dict, ...] = ()   # {"box", "what"}: the shelf does not stand as seen
    repairs: tuple[str, ...] = ()  # what the physics moved to make the perceived scene valid
    audit: str | None = None       # a record that could not be committed (persists until a capture is)
    recovered: tuple[str, ...] = ()  # runs found interrupted at start-up (crash, kill -9)
    verifications: tuple[Verification, ...] = ()  # the look after each step of the current run
    deviation: Deviation | None = None  # why the last run was held (shown until the next capture)
    message: str = ""
    error: str | None = None

    def plan_by_hash(self, plan_hash: str) -> PlanEntry | None:
        for e in self.plans.values():
            if e.hash == plan_hash:
                return e
        return None

    @property
    def phase(self) -> str:
        """The state machine's state (docs/console.md)."""
        if self.robot in ("running", "stopping"):
            return self.robot
        if self.approved is not None:
            return "approved"
        if (self.deviation is not None and not self.capturing and not self.planning
                and set(self.plans or {}) <= {"continue"}):   # held: the only offer is to continue
            return "held"
        if self.capturing:
            return "capturing"
        if self.planning:
            return "planning"
        if self.needs_recapture:
            return "finished"
        if self.plans:
            return "planned"
        return "captured" if self.scene is not None else "empty"


RobotFactory = Callable[[Scene | None, int], "RobotDriver"]   # (truth, seed) -> a driver for one run
Listener = Callable[[State], None]


class Throttle:
    """Wrong passphrases slow everybody down: per browser and overall, with doubling waits.

    After `client_free` wrong tries in a row a browser waits
    `client_base * 2**(n-1)` s (at most `client_max`) before its next try is
    even compared (a typo costs nothing); after `global_free`
    wrong tries in a row from anywhere, every browser waits
    `global_base * 2**(k)` s (at most `global_max`). A right passphrase resets
    the caller's count and the overall one.
    """

    def __init__(self, client_free: int = 2, client_base: float = 0.5, client_max: float = 60.0,
                 global_free: int = 5,
                 global_base: float = 0.5, global_max: float = 300.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.client_free, self.client_base, self.client_max = client_free, client_base, client_max
        self.global_free, self.global_base, self.global_max = global_free, global_base, global_max
        self.clock = clock
        self.lock = threading.Lock()
        self._fails: dict[str, int] = {}
        self._until: dict[str, float] = {}
        self._global_fails = 0
        self._global_until = 0.0
        self.throttled = 0           # tries refused without being compared

    def check(self, client: str, compare: Callable[[], bool]) -> bool | None:
        """True: right; False: wrong (compared); None: refused unseen (too soon). Atomic per try."""
        with self.lock:
            now = self.clock()
            if now < self._until.get(client, 0.0) or now < self._global_until:
                self.throttled += 1
                return None
            if compare():
                self._fails.pop(client, None)
                self._until.pop(client, None)
                self._global_fails = 0
                return True
            n = self._fails[client] = self._fails.get(client, 0) + 1
            if n > self.client_free:
                self._until[client] = now + min(self.client_base * 2 ** (n - 1 - self.client_free),
                                                self.client_max)
            self._global_fails += 1
            k = self._global_fails - self.global_free
            if k >= 0:
                self._global_until = now + min(self.global_base * 2 ** k, self.global_max)
            return False


@dataclass(frozen=True, eq=False)
class Deviation:
    """A run held because the shelf did not do what was predicted: what differed, and where.

    `predicted` is the shelf the plan predicted after `verification.step`
    (ids of the held plan's capture); the observed shelf is the new capture
    the workflow made current (session `session`), held from `held_session`.
    """

    verification: Verification
    predicted: Scene | None        # None: the plan had no prediction for that step
    plan: str                      # hash of the held plan
    held_session: int
    session: int | None            # the verification capture's session (plan again from it)


@dataclass(eq=False)
class _Run:
    """The run lock: one approval of one plan for one capture, until its run ends."""

    plan_hash: str
    entry: PlanEntry
    session_id: int
    gen: int
    who: str
    stop: threading.Event = field(default_factory=threading.Event)
    decision_id: int | None = None   # set once the approval is committed
    started: bool = False            # execute() took it
    thread: threading.Thread | None = None
    stopped_by: str | None = None
    audit_failed: str | None = None  # a robot event that could not be committed: the run was stopped
    scene: Scene | None = None       # the perceived and (demo) true scene of the approved capture
    truth: Scene | None = None
    robot_run: str = ""              # the run id sent to the robot (keys its "already done"); recorded
    verifications: list[Verification] = field(default_factory=list)   # one per verified step
    held: Look | None = None         # the look that held the robot (it had a frame and a perception)


class Workflow:
    """Thread-safe console state; the app calls these methods from any thread."""

    def __init__(self, source: Source | None, store: SessionStore, robot_factory: RobotFactory,
                 supervisor_passphrase: str, samples: int = 10, seed: int = 0,
                 segmenter: Segmenter | None = None, workers: int = 1, throttle: Throttle | None = None,
                 tolerance: Tolerance | None = None, perceive_options: Mapping[str, Any] | None = None) -> None:
        """`tolerance` (console.verify.Tolerance): how far a box may be from its predicted pose
        after a step before the robot is held; the look after each step needs a source with
        `look_again` (demo, files, RealSense). `perceive_options`: a cell file's `shelf` (used
        when the source knows no truth) and `catalogue` (console/cell.py)."""
        if not supervisor_passphrase:
            raise ValueError("a supervisor passphrase is required")
        self.source = source
        self.store = store
        self.robot_factory = robot_factory
        self._passphrase = supervisor_passphrase
        self.samples = int(samples)
        self.seed = int(seed)
        self.segmenter = segmenter
        self.perceive_options = dict(perceive_options or {})
        self.workers = max(1, int(workers))     # processes for the depth samples (same plans for any count)
        self.throttle = throttle or Throttle()
        from console.verify import Tolerance

        self.tolerance = tolerance or Tolerance()
        self._lock = threading.RLock()
        self._state = State(source=getattr(source, "name", str(source)))
        self._listeners: list[Listener] = []
        self._generation = 0                # bumped by every capture
        self._capturing = False
        self._plan_thread: threading.Thread | None = None
        self._run: _Run | None = None        # the run lock
        self._last_run: _Run | None = None
        self._live_stops: set[threading.Event] = set()   # Stop sets every one of them
        self._recorded: set[tuple[int, str]] = set()      # (session, plan hash) committed to the store
        self._clients: ClientPool | None = None    # Bullet clients reused by every plan
        # listeners run on one notifier thread, never under the lock: a view that holds its own
        # lock and reads `state` can then never deadlock against a change being announced
        self._notify_cv = threading.Condition()
        self._pending: State | None = None
        threading.Thread(target=self._notify_loop, name="shelfpick-notify", daemon=True).start()
        self._recover()

    def _client_pool(self) -> ClientPool:
        """The Bullet clients the plans of this console reuse (made at the first plan)."""
        from planning.bullet_clients import ClientPool

        with self._lock:
            if self._clients is None:
                self._clients = ClientPool()
            return self._clients

    def close(self) -> None:
        """Disconnect the Bullet clients the plans used (the console's shutdown; a later plan makes
        new ones)."""
        with self._lock:
            pool, self._clients = self._clients, None
        if pool is not None:
            pool.close()

    def _recover(self) -> None:
        """Runs left open by a console that died (kill -9): interrupted, in-flight steps unknown."""
        recover = getattr(self.store, "recover_interrupted", None)
        if recover is None:
            return
        try:
            found = recover()
        except Exception as exc:  # noqa: BLE001 - sqlite3, StoreError alike
            self._state = replace(self._state, audit=f"database: could not check for interrupted runs: {exc}")
            return
        notes = []
        for r in found:
            unknown = ", ".join(f"step {i + 1} ({b})" for i, b in r["unknown"])
            notes.append(f"session {r['session']} was interrupted while the robot ran (the console stopped); "
                         + (f"{unknown}: outcome unknown, check the shelf" if unknown else "no step was in flight"))
        self._state = replace(self._state, recovered=tuple(notes))

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

    def _audit_failed(self, what: str, exc: BaseException) -> str:
        """A record could not be committed: say so in the page until a capture is recorded again."""
        msg = f"database: could not record {what}: {exc}"
        self._set(audit=msg)
        return msg

    def _record(self, what: str, fn: Callable[..., Any], *args: Any, **kw: Any) -> Any:
        """Call the store for a record nothing waits on; a fault is shown (persistently), not raised."""
        try:
            return fn(*args, **kw)
        except Exception as exc:  # noqa: BLE001 - sqlite3, OSError, ShelfpickError alike
            self._audit_failed(what, exc)
            return None

    def _refuse(self, msg: str) -> None:
        self._set(error=msg)
        raise WorkflowError(msg)

    def _held(self, action: str) -> None:
        """Refuse `action` while the run lock is held (an approval pending, or the robot running)."""
        run = self._run
        if run is None:
            return
        if run.started:
            self._refuse(f"{action} refused: the robot is running; press `Stop robot` or wait")
        self._refuse(f"{action} refused: plan {run.plan_hash} is approved for this capture and about to "
                     f"run; press `Stop robot` to withdraw the approval")

    # ---------------------------------------------------------------- capture
    def capture(self) -> State:
        """New capture -> perception -> new session. Drops plans; refused while a run holds the lock."""
        with self._lock:
            if self._capturing:
                self._refuse("capture refused: a capture is already running")
            self._held("capture")
            self._capturing = True
            self._generation += 1
            gen = self._generation
            self._set(capturing=True, plans={}, approved=None, approval=None, planning=False,
                      message="capturing...", error=None)
        try:
            return self._capture(gen)
        finally:
            with self._lock:
                self._capturing = False
                if self._state.capturing:
                    self._set(capturing=False)

    def _capture(self, gen: int) -> State:
        try:
            frame = self.source.capture()
        except Exception as exc:  # noqa: BLE001 - camera faults are shown, not raised
            return self._capture_failed(f"camera: {exc}")
        try:
            from perception.pipeline import perceive

            opts = dict(self.perceive_options)
            cell_shelf = opts.pop("shelf", None)
            shelf = frame.truth.shelf if frame.truth is not None else cell_shelf  # installation geometry
            perception = perceive(frame.capture, self.segmenter, shelf=shelf, **opts)
        except Exception as exc:  # noqa: BLE001
            from perception.scene import Scene, Shelf

            shelf = frame.truth.shelf if frame.truth is not None else Shelf()
            self._record("the failed capture", self.store.new_session, self._state.source,
                         frame.capture, Scene(shelf, ()), frame.truth, None, {"error": str(exc)})
            return self._capture_failed(f"perception: {exc}", frame=frame)
        scene = perception.scene
        info = {"frame": frame.name, **_summary(perception)}
        audit = None
        try:
            sid = self.store.new_session(self._state.source, frame.capture, scene, frame.truth,
                                         perception.overlay, info)
        except Exception as exc:  # noqa: BLE001
            sid = None
            audit = (f"database: could not record this capture ({exc}); nothing can be approved or run "
                     f"until a capture is recorded")
        err = audit
        if not scene.boxes:
            err = "perception found no boxes in this capture: check the camera and the shelf, then capture again"
        target = scene.ids[-1] if scene.boxes else None
        with self._lock:
            return self._set(session_id=sid, frame_name=frame.name, capture=frame.capture,
                             overlay=perception.overlay, scene=scene, truth=frame.truth,
                             warnings=tuple(perception.warnings), target=target, task=None,
                             plans={}, capturing=False, planning=False, progress=0.0, progress_text="",
                             approved=None, approval=None, decisions=(), robot="idle", robot_events=(),
                             outcome=None, needs_recapture=False, scene_problems=(), repairs=(),
                             verifications=(), deviation=None, audit=audit, error=err,
                             message=f"captured {frame.name}: {len(scene.boxes)} boxes"
                                     + (f" (session {sid})" if sid is not None else ""))

    def _capture_failed(self, msg: str, frame: Frame | None = None) -> State:
        return self._set(capture=frame.capture if frame else None, overlay=None, scene=None,
                         truth=None, plans={}, approved=None, approval=None, decisions=(), target=None,
                         robot="idle", robot_events=(), outcome=None, planning=False, capturing=False,
                         scene_problems=(), repairs=(), session_id=None, verifications=(), deviation=None,
                         message="", error=msg)

    # ----------------------------------------------------------------- target
    def select_target(self, box_id: str) -> State:
        """A new target drops the plans made for the old one (they are no longer approvable)."""
        with self._lock:
            st = self._state
            if st.scene is None:
                self._refuse("no capture yet: press `Capture` first")
            if box_id not in st.scene.ids:
                self._refuse(f"unknown box id {box_id!r}; the scene has {', '.join(st.scene.ids) or 'no boxes'}")
            if box_id == st.target:
                return st
            self._held("changing the target")
            if self._capturing:
                self._refuse("changing the target refused: a capture is running")
            if st.planning:
                self._refuse(f"changing the target refused: planning for {st.target} is running; wait for it")
            note = f"; the plans for {st.target} are dropped, plan again" if st.plans else ""
            return self._set(target=box_id, plans={}, approved=None, approval=None, task=None,
                             scene_problems=(), repairs=(), error=None, message=f"target: {box_id}{note}")

    # --------------------------------------------------------------- planning
    def plan(self, task: str, wait: bool = False) -> State:
        """Run both planners on the perceived scene in a background worker."""
        if task not in ("extract", "clear"):
            self._refuse(f"unknown task {task!r}; expected extract or clear")
        with self._lock:
            st = self._state
            if self._capturing:
                self._refuse("planning refused: a capture is running")
            self._held("planning")
            if st.scene is None or not st.scene.boxes:
                self._refuse("nothing to plan: capture a shelf with boxes first")
            if st.needs_recapture:
                self._refuse("the shelf has changed since this capture: press `Capture` again")
            if st.planning or (self._plan_thread is not None and self._plan_thread.is_alive()):
                self._refuse("planning is already running; wait for it to finish")
            if task == "extract" and st.target is None:
                self._refuse("select a target box first")
            target = st.target if task == "extract" else None
            gen = self._generation
            scene, sid = st.scene, st.session_id
            self._plan_thread = threading.Thread(target=self._plan_worker, name="shelfpick-plan",
                                                 args=(gen, scene, sid, task, target), daemon=True)
            keep = {k: e for k, e in st.plans.items() if k == "continue"}
            self._set(planning=True, task=task, plans=keep, approved=None, approval=None, progress=0.0,
                      progress_text="starting", scene_problems=(), repairs=(), error=None,
                      message=f"planning {task}" + (f" {target}" if target else "") + "...")
            thread = self._plan_thread
        thread.start()
        if wait:
            thread.join()
        return self.state

    def wait_planning(self, timeout: float | None = None) -> State:
        t = self._plan_thread
        if t is not None:
            t.join(timeout)
        return self.state

    def _progress(self, gen: int, frac: float, text: str) -> None:
        with self._lock:
            if gen == self._generation:
                self._set(progress=frac, progress_text=text)

    def _plan_worker(self, gen: int, scene: Scene, sid: int | None, task: str, target: str | None) -> None:
        predictor = None
        try:
            from planning.predict import Predictor

            self._progress(gen, 0.05, f"building {self.samples} depth samples")
            t_setup = time.perf_counter()
            predictor = Predictor(scene, samples=self.samples, seed=self.seed, workers=self.workers,
                                  clients=self._client_pool())
            t_setup = time.perf_counter() - t_setup     # shared by both planners; charged to physics
            repairs = tuple(str(r) for r in getattr((predictor.sims or [None])[0], "repairs", ()) or ())
            entries = {p: self._one_plan(gen, i, p, scene, task, target, predictor, t_setup, repairs)
                       for i, p in enumerate(PLANNERS)}
            for e in entries.values():
                if sid is not None and self._record(f"the {e.plan.planner} plan", self.store.add_plan, sid,
                                                    e.plan, [_step_json(r) for r in e.preview]) is not None:
                    with self._lock:
                        self._recorded.add((sid, e.hash))
            self._plans_ready(gen, entries, repairs)
        except Exception as exc:  # noqa: BLE001 - shown in the page, the server keeps running
            traceback.print_exc()
            with self._lock:
                if gen == self._generation:
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

    def _one_plan(self, gen: int, i: int, planner: str, scene: Scene, task: str, target: str | None,
                  predictor: Predictor, t_setup: float, repairs: tuple[str, ...]) -> PlanEntry:
        from planning.planner import make_plan

        n = len(PLANNERS)
        self._progress(gen, 0.1 + 0.85 * i / n, f"{planner} planner: searching")
        t0 = time.perf_counter()
        plan = make_plan(scene, task, target, planner=planner, samples=self.samples,
                         seed=self.seed, predictor=predictor)
        timing = dict(plan.timing)
        timing.setdefault("planning_s", time.perf_counter() - t0)
        if planner == "physics":
            timing["setup_s"] = timing.get("setup_s", 0.0) + t_setup
        extra = dict(plan.extra)
        if repairs:
            extra["repairs"] = list(repairs)       # stored with the plan, shown in the replay
        plan = replace(plan, timing=timing, extra=extra)
        self._progress(gen, 0.1 + 0.85 * (i + 0.6) / n, f"{planner} planner: recording preview")
        preview = tuple(predictor.preview(plan.sequence, 0)) if plan.sequence else ()
        from planning.predicted import predicted_shelves

        shelves = tuple(predicted_shelves(scene, plan.sequence, preview)) if preview else ()
        return PlanEntry(plan, plan.content_hash(), preview, shelves)

    def _plans_ready(self, gen: int, entries: dict[str, PlanEntry], repairs: tuple[str, ...]) -> None:
        phys = entries["physics"].plan
        problems = scene_problems(phys)
        with self._lock:
            if gen != self._generation:
                return  # a new capture arrived meanwhile: these plans are for the old shelf
            err = None
            if problems:
                err = ("the shelf does not stand as seen: " + "; ".join(problem_text(p) for p in problems)
                       + ". No plan on it is safe: check the shelf and capture again, or a supervisor "
                         "approves only by accepting the predicted risk")
            elif not phys.safe:
                err = (f"no safe plan: the least risky sequence still has a predicted collapse "
                       f"risk of {100 * phys.risk:.0f}%; a supervisor may approve it only by "
                       f"accepting that risk. Or rearrange the shelf and capture again")
            cont = self._state.plans.get("continue")   # continuing the held plan stays on offer
            if cont is not None:
                entries = {**entries, "continue": cont}
            self._set(plans=entries, planning=False, progress=1.0, progress_text="done", error=err,
                      scene_problems=problems, repairs=repairs,
                      message="plans ready: compare them, preview, then a supervisor approves one")

    # ------------------------------------------------------------- supervisor
    def _authenticate(self, plan_hash: str, passphrase: str, who: str, action: str, client: str) -> None:
        """Throttled passphrase check; every refusal reads the same, wrong or too soon."""
        secret = self._passphrase.encode()
        given = (passphrase or "").encode()
        verdict = self.throttle.check(client, lambda: hmac.compare_digest(given, secret))
        if verdict:
            return
        st = self.state
        if verdict is False:
            if st.session_id is not None:
                # the store's decisions are approve/reject only: a refused attempt is an event
                self._record("the refused attempt", self.store.add_robot_event, st.session_id, plan_hash,
                             "auth_refused", None, None,
                             {"who": who or "?", "action": action, "client": client,
                              "reason": "wrong supervisor passphrase",
                              "throttled_so_far": self.throttle.throttled})
            with self._lock:
                self._set(decisions=self._state.decisions + (
                    {"decision": "refused", "plan": plan_hash, "who": who,
                     "reason": f"{action}: wrong passphrase", "at": time.time()},))
        self._refuse(f"{action} refused: {AUTH_REFUSED}")

    def _decidable(self, plan_hash: str, action: str) -> tuple[PlanEntry, int]:
        """What every decision needs, checked before the passphrase (so no refusal tells it was right)."""
        st = self._state
        if self._capturing:
            self._refuse(f"{action} refused: a capture is running")
        if st.planning:
            self._refuse(f"{action} refused: planning is still running")
        entry = st.plan_by_hash(plan_hash)
        if entry is None:
            self._refuse(f"{action} refused: plan {plan_hash} is not a plan for the current capture")
        if st.session_id is None:
            self._refuse(f"{action} refused: this capture has no session record ({st.audit or 'database'}); "
                         f"capture again once the database can be written")
        if (st.session_id, plan_hash) not in self._recorded:
            self._refuse(f"{action} refused: plan {plan_hash} was not recorded ({st.audit or 'database'}); "
                         f"plan again once the database can be written")
        return entry, st.session_id

    def approve(self, plan_hash: str, passphrase: str, who: str = "supervisor",
                accept_risk: bool = False, client: str = "local") -> State:
        """Approve exactly this plan for exactly the current capture; takes the run lock.

        A plan predicted unsafe (the least risky one when no safe plan exists,
        or any plan on a shelf that does not stand as seen) needs
        `accept_risk`. The approval counts once its decision is committed; of
        two supervisors approving at once exactly one gets it.
        """
        who = (who or "supervisor")[:80]
        with self._lock:
            entry, sid = self._decidable(plan_hash, "approval")
            if self._state.needs_recapture:
                self._refuse("approval refused: the shelf has changed, capture and plan again")
            self._held("approval")
            risk_note = self._risk_note(entry, accept_risk)
        self._authenticate(plan_hash, passphrase, who, "approval", client)
        with self._lock:   # the state may have moved while the passphrase was checked
            entry, sid = self._decidable(plan_hash, "approval")
            self._held("approval")
            run = self._run = _Run(plan_hash, entry, sid, self._generation, who)
            self._live_stops.add(run.stop)
        try:
            run.decision_id = self.store.add_decision(sid, plan_hash, "approve", who, risk_note)
        except Exception as exc:  # noqa: BLE001 - audit first: an unrecorded approval is no approval
            with self._lock:
                self._release(run)
            msg = self._audit_failed("the approval", exc)
            self._refuse(f"approval refused: the decision could not be recorded, nothing will run ({msg})")
        with self._lock:
            if self._run is not run:     # Stop withdrew it while it was being recorded
                self._refuse("approval withdrawn: `Stop robot` was pressed while it was being recorded")
            dec = {"decision": "approve", "plan": plan_hash, "planner": entry.plan.planner,
                   "who": who, "reason": risk_note, "at": time.time()}
            approval = {"plan": plan_hash, "session": sid, "capture": self._state.frame_name,
                        "who": who, "decision": run.decision_id}
            return self._set(approved=plan_hash, approval=approval, decisions=self._state.decisions + (dec,),
                             error=None, message=f"{who} approved the {entry.plan.planner} plan {plan_hash}")

    def _risk_note(self, entry: PlanEntry, accept_risk: bool) -> str | None:
        cont = (entry.plan.extra or {}).get("continues")
        if isinstance(cont, Mapping):
            # the shelf already did not do what this plan predicted: continuing is a risk taken knowingly
            what = (f"continue plan {cont.get('plan')} as planned after a deviation at step "
                    f"{int(cont.get('after_step', 0)) + 1} (session {cont.get('session')})")
            if not accept_risk:
                self._refuse(f"approval refused: to {what}, tick 'Accept predicted risk' (the shelf "
                             f"differs from the prediction); or plan again from the new capture")
            return f"accepted: {what}"
        if entry.plan.safe:
            return None
        risk = f"{100 * entry.plan.risk:.0f}%"
        why = (f"the shelf does not stand as seen ({len(entry.scene_problems)} problem(s))"
               if entry.scene_problems else f"collapse risk up to {risk}")
        if not accept_risk:
            self._refuse(f"approval refused: the {entry.plan.planner} plan is predicted unsafe "
                         f"({why}); tick 'Accept predicted risk' to approve it anyway")
        return f"accepted predicted risk {risk}" + (
            f"; scene problems: {'; '.join(problem_text(p) for p in entry.scene_problems)}"
            if entry.scene_problems else "")

    def _release(self, run: _Run) -> None:
        """Give the run lock back (under self._lock)."""
        if self._run is run:
            self._run = None
        self._live_stops.discard(run.stop)

    def reject(self, plan_hash: str, passphrase: str, who: str = "supervisor", reason: str = "",
               client: str = "local") -> State:
        """Reject a plan; rejecting the approved plan before it runs withdraws the approval."""
        if not (reason or "").strip():
            self._refuse("reject needs a reason")
        who, reason = (who or "supervisor")[:80], reason.strip()[:500]
        with self._lock:
            entry, sid = self._decidable(plan_hash, "rejection")
            if self._run is not None and self._run.started:
                self._refuse("rejection refused: the robot is running; press `Stop robot`")
        self._authenticate(plan_hash, passphrase, who, "rejection", client)
        with self._lock:
            run = self._run
            if run is not None and run.plan_hash == plan_hash and not run.started:
                self._release(run)
            elif run is not None and run.started:
                self._refuse("rejection refused: the robot is running; press `Stop robot`")
            dec = {"decision": "reject", "plan": plan_hash, "planner": entry.plan.planner,
                   "who": who, "reason": reason, "at": time.time()}
            approved = None if self._state.approved == plan_hash else self._state.approved
            self._set(approved=approved, approval=None if approved is None else self._state.approval,
                      decisions=self._state.decisions + (dec,), error=None,
                      message=f"{who} rejected the {entry.plan.planner} plan: {reason}")
        self._record("the rejection", self.store.add_decision, sid, plan_hash, "reject", who, reason)
        return self.state

    # ------------------------------------------------------------------ robot
    def execute(self, wait: bool = False) -> State:
        """Send the approved plan to the robot on a background thread, once its start is committed."""
        with self._lock:
            run, st = self._run, self._state
            if run is None or st.approved is None:
                self._refuse("nothing approved: a supervisor must approve a plan first")
            if run.started:
                self._refuse("the robot is already running")
            if run.decision_id is None or st.approved != run.plan_hash:
                self._refuse("the approval is still being recorded; try again in a moment")
            if (run.session_id != st.session_id or run.gen != self._generation
                    or st.plan_by_hash(run.plan_hash) is None or st.needs_recapture):
                self._release(run)
                self._refuse("the approved plan is not for the current capture")
            run.started = True       # the approval is used up: re-running would re-send steps
            run.scene, run.truth = st.scene, st.truth
            self._set(approved=None, robot="running", robot_events=(), outcome=None, error=None,
                      message=f"robot: starting the {run.entry.plan.planner} plan {run.plan_hash}")
        try:
            from console.robot_types import new_run_id

            done = self._steps_before(run)
            run.robot_run = new_run_id(f"s{run.session_id}-")
            rid = self.store.start_run(run.session_id, run.plan_hash, run.decision_id,
                                       {"sequence": list(run.entry.plan.sequence), "who": run.who,
                                        "robot_run": run.robot_run})
        except Exception as exc:  # noqa: BLE001 - audit first: no committed start, no motion
            msg = exc.args[0] if isinstance(exc, WorkflowError) else self._audit_failed("the robot start", exc)
            with self._lock:
                self._release(run)
                self._set(robot="idle", approval=None)
            self._refuse(f"robot not started: {msg}")
        run.thread = threading.Thread(target=self._robot_worker, name="shelfpick-robot",
                                      args=(run, rid, done), daemon=True)
        with self._lock:
            self._last_run = run
        run.thread.start()
        if wait:
            run.thread.join()
        return self.state

    def _steps_before(self, run: _Run) -> dict[int, str]:
        """Steps of this plan this session already ran (from the database): done ones are skipped,
        an unknown one refuses this plan for this capture only."""
        states = self.store.step_states(run.session_id, run.plan_hash) if hasattr(self.store, "step_states") else {}
        for i, (state, box) in sorted(states.items()):
            if state in ("unknown", "in_flight"):
                raise WorkflowError(f"step {i + 1} ({box}) of plan {run.plan_hash} has an unknown outcome "
                                    f"for this capture, so this plan is not sent again; capture again to "
                                    f"see the shelf as it is now")
        return {i: box for i, (state, box) in states.items() if state == "done" and box is not None}

    def wait_robot(self, timeout: float | None = None) -> State:
        run = self._last_run
        if run is not None and run.thread is not None:
            run.thread.join(timeout)
        return self.state

    def stop(self, who: str = "operator") -> State:
        """Stop reaches every run: it aborts a running one and withdraws an approval not yet run."""
        with self._lock:
            for ev in list(self._live_stops):
                ev.set()
            run = self._run
            if run is not None:
                run.stopped_by = who
            if run is None:
                st = self._set(message="robot is not running")
            elif run.started:
                st = self._set(robot="stopping", message=f"{who} pressed Stop robot: aborting remaining steps")
            else:
                self._release(run)
                st = self._set(approved=None, approval=None,
                               message=f"{who} pressed Stop robot: the approval of plan {run.plan_hash} "
                                       f"is withdrawn; nothing was sent")
        if run is not None:
            self._record("the stop", self.store.add_robot_event, run.session_id, run.plan_hash, "stop",
                         None, None, {"who": who, "running": run.started})
        return st

    def _robot_worker(self, run: _Run, run_id: int, done_before: dict[int, str]) -> None:
        outcome, err = None, None
        try:
            robot = self.robot_factory(run.truth, self.seed)
            _seed_history(robot, run.plan_hash, done_before)
            if hasattr(robot, "run_id"):
                robot.run_id = run.robot_run
            if hasattr(robot, "verify") and callable(getattr(self.source, "look_again", None)):
                robot.verify = self._verifier(run)
            if run.stop.is_set():
                err = "robot: stopped before the first step"
            else:
                self._set(message=f"robot: executing the {run.entry.plan.planner} plan {run.plan_hash}")
                outcome = robot.execute(run.entry.plan, run.scene, self._on_event(run), run.stop)
                err = None if outcome.ok else f"robot: {outcome.error or 'the plan did not succeed'}"
        except Exception as exc:  # noqa: BLE001 - robot refused / unreachable
            traceback.print_exc()
            err = f"robot: {exc}"
        finally:
            self._finish(run, run_id, outcome, err)

    def _verifier(self, run: _Run) -> Callable[..., str | None]:
        """After each `done`: look again, compare with the predicted shelf; a reason string holds the robot.

        Runs on the robot's thread before the next step is sent. The record is
        committed before the answer is given (audit first): a verification
        that cannot be recorded, or cannot be made, holds the robot too.
        """
        def verify(step: int, box: str, world: Scene | None = None) -> str | None:
            from console.verify import unavailable

            look = self._look(run, step, box, world)
            v, perception, predicted = look.verification, look.perception, look.predicted
            try:
                self.store.add_verification(run.session_id, run.plan_hash, run.robot_run, v.to_json(), predicted,
                                            perception.scene if perception is not None else None)
            except Exception as exc:  # noqa: BLE001 - audit first: no record, no further motion
                msg = self._audit_failed(f"the verification of step {step + 1}", exc)
                v = unavailable(step, box, f"the verification could not be recorded ({msg})", self.tolerance)
            run.verifications.append(v)
            with self._lock:
                self._set(verifications=tuple(run.verifications), message=v.summary())
            if v.within:
                return None
            if look.frame is not None and perception is not None:
                run.held = look._replace(verification=v)
            return v.summary()
        return verify

    def _look(self, run: _Run, step: int, box: str, world: Scene | None) -> Look:
        """The look after `step`: the new frame compared with the shelf the plan predicted."""
        shelves = run.entry.shelves
        predicted = shelves[step] if step < len(shelves) else None
        removed = run.scene.box(box) if box in run.scene.ids else None
        return look_again(self.source, world, step, box, predicted, run.scene.shelf, self.segmenter,
                          self.tolerance, self.perceive_options, removed)

    def _on_event(self, run: _Run) -> Callable[[RobotEvent], None]:
        def on_event(ev: RobotEvent) -> None:
            try:
                self.store.add_robot_event(run.session_id, run.plan_hash, ev.kind, ev.step, ev.box,
                                           dict(ev.detail) if ev.detail else None)
            except Exception as exc:  # noqa: BLE001 - audit first: no record, no further motion
                run.stop.set()
                run.audit_failed = self._audit_failed(f"a robot event ({ev.kind})", exc) + "; the robot was stopped"
            with self._lock:
                events = self._state.robot_events + (ev,)
                step = f" step {ev.step + 1}" if isinstance(ev.step, int) else ""
                self._set(robot_events=events, message=f"robot: {ev.kind}{step}" + (f" ({ev.box})" if ev.box else ""))
        return on_event

    def _finish(self, run: _Run, run_id: int, outcome: RobotOutcome | None, err: str | None) -> None:
        stop_asked = run.stop.is_set()
        ok = outcome is not None and outcome.ok
        if stop_asked and not ok:
            status, msg = "stopped", (f"robot stopped ({run.stopped_by} pressed Stop robot)" if run.stopped_by
                                      else "robot stopped")
        elif ok:
            status, msg = "done", "robot finished the plan"
        else:
            status, msg = "failed", "robot stopped on an error"
        if run.held is not None and status == "failed":
            status, msg = "held", f"robot held: {run.held.verification.summary()}"
        elif run.verifications and not run.verifications[-1].within and status == "failed":
            status, msg = "held", f"robot held: {run.verifications[-1].summary()}"
        if run.audit_failed:
            status, err = "stopped", run.audit_failed
        out_doc = _outcome_json(outcome, err, run.entry, stop_asked, run.stopped_by)
        if run.verifications:
            out_doc["verified"] = [v.to_json() for v in run.verifications]
            out_doc["held"] = status == "held"
        self._record("the outcome", self.store.set_outcome, run.session_id, out_doc, run_id)
        done = ", ".join(outcome.completed) if outcome is not None and outcome.completed else "none"
        if run.held is not None:
            try:
                if self._held_capture(run, status, outcome, msg, err):
                    return
            except Exception as exc:  # noqa: BLE001 - the run lock must be released whatever happens
                traceback.print_exc()
                self._audit_failed("the capture taken after the held step", exc)
        msg += f"; completed steps: {done}. Capture and plan again before the next run."
        with self._lock:
            self._release(run)
            self._set(robot=status, outcome=outcome, needs_recapture=True, approval=None, message=msg,
                      error=err if status not in ("stopped", "held") or run.audit_failed else None)

    def _held_capture(self, run: _Run, status: str, outcome: RobotOutcome | None, msg: str,
                      err: str | None) -> bool:
        """The look that held the robot becomes the current capture: plan again from it, or continue.

        A new session (its images and perceived scene, linked to the held one)
        and, when every box the held plan still has to take was seen, a
        `continue` plan: the rest of the held plan in the new capture's ids,
        which a supervisor may approve (ticking `Accept predicted risk`).
        """
        v, frame, perception, predicted = run.held   # set only with a frame and its perception
        info = {"frame": frame.name, **_summary(perception),
                "verification_of": {"session": run.session_id, "plan": run.plan_hash, "step": v.step,
                                    "run": run.robot_run}}
        try:
            sid = self.store.new_session(self._state.source, frame.capture, perception.scene, frame.truth,
                                         perception.overlay, info)
        except Exception as exc:  # noqa: BLE001 - no record, nothing of it can be approved: fall back
            self._audit_failed("the capture taken after the held step", exc)
            return False
        cont = _continuation(run.entry, v, perception.scene, run.session_id)
        recorded = False
        if cont is not None:
            recorded = self._record("the continue-as-planned plan", self.store.add_plan, sid, cont.plan,
                                    [r if isinstance(r, Mapping) else _step_json(r)
                                     for r in cont.preview]) is not None
        scene = perception.scene
        with self._lock:
            self._generation += 1
            if recorded:
                self._recorded.add((sid, cont.hash))
            self._release(run)
            dev = Deviation(v, predicted, run.plan_hash, run.session_id, sid)
            msg += (f". The new capture (session {sid}) is current: plan again from it"
                    + (", or a supervisor approves `continue` (the rest of the plan as planned)"
                       if recorded else "") + ".")
            self._set(session_id=sid, frame_name=frame.name, capture=frame.capture, overlay=perception.overlay,
                      scene=scene, truth=frame.truth, warnings=tuple(perception.warnings),
                      target=_mapped_target(run.entry.plan, v, scene), task=None,
                      plans={"continue": cont} if recorded else {}, planning=False, progress=0.0,
                      progress_text="", approved=None, approval=None, decisions=(), robot=status,
                      outcome=outcome, needs_recapture=False, scene_problems=(), repairs=(),
                      deviation=dev, message=msg, error=v.summary() if status == "held" else err)
        return True


class Look(NamedTuple):
    """One look after a step: the verdict, the frame and its perception (None when there was no
    frame or perception failed) and the shelf the plan predicted (None: no prediction)."""

    verification: Verification
    frame: Frame | None
    perception: Perception | None
    predicted: Scene | None


def look_again(source: Source, world: Scene | None, step: int, box: str, predicted: Scene | None,
               shelf: Shelf | None, segmenter: Segmenter | None = None, tolerance: Tolerance | None = None,
               perceive_options: Mapping[str, Any] | None = None, removed: Box | None = None,
               confirm: bool = True) -> Look:
    """The console's look after `step`: a new frame, perceived, compared with the `predicted` shelf.

    Returns a `Look` (verification, frame, perception, predicted). A
    camera or perception fault, no new frame or no prediction is a verdict
    that holds (`unavailable`), never an exception. `shelf`: the installation's
    shelf when the frame knows no truth; `removed`: the box the step took out, as
    perceived (a box it hid is not new). A difference is looked at a second time
    (`confirm`): a box that moved is still moved in the next frame, a face that
    perception cut differently in one frame mostly is not; when the second look
    finds the shelf as predicted the step passes, the first look's summary kept
    in `unconfirmed`; when it cannot be made the first verdict stands (hold).
    benchmarks/closed_loop.py times and scores exactly this function.
    """
    first = _look_once(source, world, step, box, predicted, shelf, segmenter, tolerance, perceive_options,
                       removed, 0)
    v = first.verification
    if not confirm or v.within or v.unavailable:
        return first
    second = _look_once(source, world, step, box, predicted, shelf, segmenter, tolerance, perceive_options,
                        removed, 1)
    v2 = second.verification
    timing = {k: v.timing.get(k, 0.0) + v2.timing.get(k, 0.0) for k in v.timing}
    if v2.within:
        return second._replace(verification=replace(v2, timing=timing, unconfirmed=v.summary()))
    if v2.unavailable:
        return first._replace(verification=replace(v, timing=timing))
    return second._replace(verification=replace(v2, timing=timing))


def _look_once(source: Source, world: Scene | None, step: int, box: str, predicted: Scene | None,
               shelf: Shelf | None, segmenter: Segmenter | None, tolerance: Tolerance | None,
               perceive_options: Mapping[str, Any] | None, removed: Box | None, attempt: int) -> Look:
    """One frame, perceived and compared."""
    from console.verify import Tolerance, compare, unavailable
    from perception.pipeline import perceive

    tol = tolerance or Tolerance()
    t0 = time.perf_counter()
    try:
        frame = source.look_again(world, step, attempt) if attempt else source.look_again(world, step)
    except Exception as exc:  # noqa: BLE001 - a camera fault holds the robot, it is not a crash
        return Look(unavailable(step, box, f"camera: {exc}", tol), None, None, predicted)
    if frame is None:
        return Look(unavailable(step, box, "the source has no new frame since the last capture", tol), None, None,
                    predicted)
    t1 = time.perf_counter()
    try:
        opts = {k: v for k, v in (perceive_options or {}).items() if k != "shelf"}
        perception = perceive(frame.capture, segmenter,
                              shelf=frame.truth.shelf if frame.truth is not None else shelf, **opts)
    except Exception as exc:  # noqa: BLE001
        return Look(unavailable(step, box, f"perception: {exc}", tol), frame, None, predicted)
    t2 = time.perf_counter()
    if predicted is None:
        v = unavailable(step, box, "the plan has no predicted shelf for this step", tol)
    else:
        v = compare(predicted, perception.scene, step, box, tol, removed)
    t3 = time.perf_counter()
    return Look(replace(v, timing={"capture_s": t1 - t0, "perceive_s": t2 - t1, "compare_s": t3 - t2}), frame,
                perception, predicted)


def _seed_history(robot: RobotDriver, plan_hash: str, done: dict[int, str]) -> None:
    """Give the driver the step history of this run: what this session already did, nothing else.

    The workflow owns it: seeded from the database (`store.step_states`, the
    never-re-send that survives a restart) and handed to the driver, which
    keys it by plan hash alone; a new capture with the same sequence is a new
    run, so each run gets a fresh one. A driver without a `history` (the sim
    robot, whose world is new every run) keeps its own.
    """
    if not hasattr(robot, "history"):
        return
    from console.robot_types import StepHistory

    hist = StepHistory()
    for i, box in done.items():
        hist.mark_done(getattr(robot, "name", ""), plan_hash, i, box)
    robot.history = hist


def _mapped_target(plan: Plan, v: Verification, scene: Scene) -> str | None:
    """The held plan's target in the new capture's ids (else the new capture's last box)."""
    t = v.observed_of().get(plan.target) if plan.target else None
    return t or (scene.ids[-1] if scene.boxes else None)


def _continuation(entry: PlanEntry, v: Verification, scene: Scene, held_session: int) -> PlanEntry | None:
    """The rest of the held plan in the new capture's ids; None when a box still to take was not seen.

    Its predicted shelves carry the held plan's simulated motions on from
    where the prediction stood after the held step, applied to the new
    capture's boxes, so the continued run is verified step by step too.
    """
    from planning.plan import StepPrediction
    from planning.predicted import predicted_shelves, sim_poses_after

    plan, k = entry.plan, v.step
    rest = plan.sequence[k + 1:]
    ids = v.observed_of()
    if not rest or any(b not in ids for b in rest):
        return None
    seq = tuple(ids[b] for b in rest)
    pred = tuple(StepPrediction(ids[p.box], p.collapse_prob, p.collision_prob,
                                tuple(ids[m] for m in p.moved if m in ids))
                 for p in plan.predicted[k + 1:] if p.box in ids)
    extra = {"continues": {"session": held_session, "plan": entry.hash, "after_step": k,
                           "deviation": v.summary()}}
    if plan.target is None:
        target = None
    else:
        target = ids[plan.target]
    cont = replace(plan, target=target, planner="continue", sequence=seq, predicted=pred,
                   timing={}, extra=extra)
    preview = tuple(_renamed(r, ids) for r in entry.preview[k + 1:])
    start = _renamed_poses(sim_poses_after(entry.preview, k), ids) if entry.preview else None
    shelves = tuple(predicted_shelves(scene, seq, preview, start)) if preview else ()
    return PlanEntry(cont, cont.content_hash(), preview, shelves)


def _renamed_poses(poses: Mapping[str, Any], ids: Mapping[str, str]) -> dict[str, Any]:
    return {ids[b]: p for b, p in poses.items() if b in ids}


def _renamed(step: PreviewStep, ids: Mapping[str, str]) -> dict[str, Any]:
    """A recorded preview step (object or JSON) with the box ids of another capture."""
    doc = _step_json(step) if not isinstance(step, Mapping) else dict(step)
    doc["box"] = ids.get(doc.get("box"), doc.get("box"))
    for k in ("collapsed", "collided"):
        doc[k] = [ids[b] for b in doc.get(k, []) if b in ids]
    doc["frames"] = [[t, _renamed_poses(poses, ids)] for t, poses in doc.get("frames", [])]
    return doc


def scene_problems(plan: Plan) -> tuple[dict, ...]:
    """plan.extra["scene_check"]["problems"] when the shelf does not stand as seen, else ()."""
    check = (plan.extra or {}).get("scene_check") or {}
    if not isinstance(check, Mapping) or check.get("stands_as_seen", True):
        return ()
    probs = check.get("problems") or [{"box": None, "what": "does not stand as seen"}]
    return tuple({"box": p.get("box"), "what": str(p.get("what", ""))} for p in probs if isinstance(p, Mapping))


def problem_text(p: Mapping[str, Any]) -> str:
    return (f"box {p['box']}" if p.get("box") else "the scene") + f" {p.get('what', '')}".rstrip()


def _summary(perception: Perception) -> dict:
    try:
        return dict(perception.summary())
    except Exception:  # noqa: BLE001 - an older Perception without summary()
        return {"warnings": list(perception.warnings), "timing": dict(perception.timing)}


def _step_json(result: PreviewStep) -> dict:
    """A preview step with its recorded frames, so a replay can animate it without the server."""
    try:
        return result.to_json(frames=True)
    except TypeError:
        return result.to_json()


def _outcome_json(outcome: RobotOutcome | None, err: str | None, entry: PlanEntry, stopped: bool,
                  stopped_by: str | None = None) -> dict:
    doc: dict[str, Any] = {"plan": entry.hash, "planner": entry.plan.planner,
                           "sequence": list(entry.plan.sequence), "stopped": stopped}
    if stopped_by:
        doc["stopped_by"] = stopped_by
    if outcome is not None:
        doc.update({"completed": list(outcome.completed), "ok": bool(outcome.ok), "error": outcome.error or err,
                    "steps": [dict(s) for s in outcome.steps]})
    else:
        doc.update({"completed": [], "ok": False, "error": err, "steps": []})
    return doc


__all__ = ["Workflow", "WorkflowError", "State", "PlanEntry", "Deviation", "Throttle", "PLANNERS", "SECONDS_PER_BOX",
           "AUTH_REFUSED", "scene_problems", "problem_text"]
