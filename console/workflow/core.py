"""The workflow's core: one lock over one immutable `State`, its listeners, and the refusals.

viser runs callbacks on a thread pool, so two browsers can press buttons at
the same moment: every state change happens under `_lock`, and the slow
parts (capture, planning, the robot) run outside it, guarded by flags taken
under it. Listeners hear of each change on one notifier thread, never under
the lock. The stages (`console.workflow.planning_stage`, `console.workflow.supervision`,
`console.workflow.run`) and `console.workflow.machine.Workflow` build on this class and
share exactly the attributes its `__init__` sets.
"""
from __future__ import annotations

import threading
import traceback
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Callable, Mapping

from shelfpick.console.workflow.state import Listener, RobotFactory, RunLock, State, WorkflowError
from shelfpick.console.workflow.throttle import Throttle

if TYPE_CHECKING:
    from shelfpick.console.sources import Source
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.verify import Tolerance
    from shelfpick.perception.segment import Segmenter
    from shelfpick.planning.bullet_clients import ClientPool
    from shelfpick.planning.predict import Predictor


class WorkflowCore:
    """Thread-safe console state: the lock, the snapshot, the listeners, the run lock's holder."""

    def __init__(self, source: Source | None, store: SessionStore, robot_factory: RobotFactory,
                 supervisor_passphrase: str, samples: int = 10, seed: int = 0,
                 segmenter: Segmenter | None = None, workers: int = 1, throttle: Throttle | None = None,
                 tolerance: Tolerance | None = None, perceive_options: Mapping[str, Any] | None = None,
                 priors: Any = None) -> None:
        """`tolerance` (console.workflow.verify.Tolerance): how far a box may be from its predicted pose
        after a step before the robot is held; the look after each step needs a source with
        `look_again` (demo, files, RealSense). `perceive_options`: a cell file's `shelf` (used
        when the source knows no truth) and `catalogue` (console/cell.py). `priors`
        (planning.priors.CellPriors): the cell's masses, friction, pull modes and plan threshold."""
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
        from shelfpick.planning.priors import CellPriors

        self.priors = priors if priors is not None else CellPriors()   # the cell's [planning] section
        self.throttle = throttle or Throttle()
        from shelfpick.console.workflow.verify import Tolerance

        self.tolerance = tolerance or Tolerance()
        self._lock = threading.RLock()
        self._state = State(source=getattr(source, "name", str(source)))
        self._listeners: list[Listener] = []
        self._generation = 0                # bumped by every capture
        self._capturing = False
        self._plan_thread: threading.Thread | None = None
        self._run: RunLock | None = None        # the run lock
        self._last_run: RunLock | None = None
        self._live_stops: set[threading.Event] = set()   # Stop sets every one of them
        self._recorded: set[tuple[int, str]] = set()      # (session, plan hash) committed to the store
        self._clients: ClientPool | None = None    # Bullet clients reused by every plan
        self._planning_pool: ClientPool | None = None   # the pool a running plan worker took its clients from
        self._close_after_plan: ClientPool | None = None  # that pool, when close() left it to the worker
        # the last plan's Predictor and its capture's generation, kept for the next plan of that
        # capture: its sample worlds are the same, so the plans are too
        self._kept: tuple[int, Predictor, Any] | None = None   # gen, predictor, its SetAside
        self._epoch = 0                     # bumped by close(): a predictor taken before is not kept
        # listeners run on one notifier thread, never under the lock: a view that holds its own
        # lock and reads `state` can then never deadlock against a change being announced
        self._notify_cv = threading.Condition()
        self._pending: State | None = None
        self._notifier: threading.Thread | None = None     # started by the first change, ended by close()
        self._recover()

    def _client_pool(self) -> ClientPool:
        """The Bullet clients the plans of this console reuse (made at the first plan). The plan
        worker takes it once (`_planning_pool`) and hands it back with `_plan_pool_done`: close()
        never disconnects the clients a running plan holds, it leaves that pool to the worker."""
        from shelfpick.planning.bullet_clients import ClientPool

        with self._lock:
            if self._clients is None:
                self._clients = ClientPool()
            return self._clients

    def _plan_pool_done(self) -> None:
        """The plan worker is done with its clients: a pool close() left to it is closed now."""
        with self._lock:
            self._planning_pool = None
            pool, self._close_after_plan = self._close_after_plan, None
        if pool is not None:
            pool.close()

    def close(self) -> None:
        """Close the kept Predictor (and its worker processes), disconnect the Bullet clients the
        plans used, release the source's camera (one that has a `close`: a RealSense) and end the
        notifier thread once it has announced the last change (the console's shutdown; a later
        plan, capture or change starts them again)."""
        with self._lock:
            pool, self._clients = self._clients, None
            kept, self._kept = self._kept, None
            self._epoch += 1
            if pool is not None and pool is self._planning_pool:
                self._close_after_plan = pool    # a plan still simulates with its clients
                pool = None
        if kept is not None:
            close_quietly(kept[1])
        if pool is not None:
            pool.close()
        release = getattr(self.source, "close", None)
        if callable(release):
            try:
                release()
            except Exception:  # noqa: BLE001 - a camera that is already gone
                pass
        with self._notify_cv:
            notifier, self._notifier = self._notifier, None
            self._notify_cv.notify_all()
        if notifier is not None and notifier is not threading.current_thread():
            notifier.join(5)

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
            if self._notifier is None:
                self._notifier = threading.Thread(target=self._notify_loop, name="shelfpick-notify", daemon=True)
                self._notifier.start()
            self._notify_cv.notify_all()
        return snap

    def _notify_loop(self) -> None:
        """Hand the newest state to every listener, in version order (intermediate ones may be skipped)."""
        me, last = threading.current_thread(), -1
        while True:
            with self._notify_cv:
                while self._pending is None and self._notifier is me:
                    self._notify_cv.wait()
                if self._notifier is not me and (self._pending is None or self._notifier is not None):
                    return      # closed with nothing left to announce, or a newer notifier took over
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

    def _release(self, run: RunLock) -> None:
        """Give the run lock back (under self._lock)."""
        if self._run is run:
            self._run = None
        self._live_stops.discard(run.stop)


def close_quietly(predictor: Predictor) -> None:
    """Close a Predictor whatever state its workers are in (they may already be gone)."""
    try:
        predictor.close()
    except Exception:  # noqa: BLE001
        pass


__all__ = ["WorkflowCore", "close_quietly"]
