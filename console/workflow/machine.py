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

from typing import TYPE_CHECKING

from shelfpick.planning.plan import PLANNERS  # noqa: F401 - the planners the console runs side by side (re-exported)

from shelfpick.console.workflow.look import Look, look_again  # noqa: F401 - re-exported (benchmarks/closed_loop.py)
from shelfpick.console.workflow.planning_stage import PlanningStage
from shelfpick.console.workflow.run import RobotRun
from shelfpick.console.workflow.run_json import perception_summary
from shelfpick.console.workflow.state import (AUTH_REFUSED, SECONDS_PER_BOX, Deviation, PlanEntry, State,  # noqa: F401
                                              WorkflowError, problem_text, scene_problems)
from shelfpick.console.workflow.supervision import Supervision
from shelfpick.console.workflow.throttle import Throttle  # noqa: F401 - re-exported

if TYPE_CHECKING:
    from shelfpick.console.sources import Frame


class Workflow(PlanningStage, Supervision, RobotRun):
    """Thread-safe console state; the app calls these methods from any thread.

    Built from its stages: `WorkflowCore` (state, lock, listeners,
    refusals), `PlanningStage`, `Supervision` and `RobotRun`; capture and the
    target live here. The constructor is `WorkflowCore.__init__`.
    """

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
                      run_end=None, message="capturing...", error=None)
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
            from shelfpick.perception.pipeline import perceive

            opts = dict(self.perceive_options)
            cell_shelf = opts.pop("shelf", None)
            shelf = frame.truth.shelf if frame.truth is not None else cell_shelf  # installation geometry
            perception = perceive(frame.capture, self.segmenter, shelf=shelf, **opts)
        except Exception as exc:  # noqa: BLE001
            from shelfpick.perception.scene import Scene, Shelf

            shelf = frame.truth.shelf if frame.truth is not None else Shelf()
            self._record("the failed capture", self.store.new_session, self._state.source,
                         frame.capture, Scene(shelf, ()), frame.truth, None, {"error": str(exc)})
            return self._capture_failed(f"perception: {exc}", frame=frame)
        scene = perception.scene
        info = {"frame": frame.name, **perception_summary(perception)}
        audit = None
        try:
            sid = self.store.new_session(self._state.source, frame.capture, scene, frame.truth,
                                         perception.overlay, info, labels=perception.masks,
                                         matter=perception.unexplained_labels)
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
                             overlay=perception.overlay, labels=perception.masks,
                             matter=perception.unexplained_labels, scene=scene, truth=frame.truth,
                             warnings=tuple(perception.warnings), target=target, task=None,
                             plans={}, capturing=False, planning=False, progress=0.0, progress_text="",
                             approved=None, approval=None, decisions=(), robot="idle", robot_events=(),
                             outcome=None, needs_recapture=False, scene_problems=(), repairs=(),
                             verifications=(), deviation=None, run_end=None, audit=audit, error=err,
                             message=f"captured {frame.name}: {len(scene.boxes)} boxes"
                                     + (f" (session {sid})" if sid is not None else ""))

    def _capture_failed(self, msg: str, frame: Frame | None = None) -> State:
        return self._set(capture=frame.capture if frame else None, overlay=None, labels=None, matter=None,
                         scene=None, truth=None, plans={}, approved=None, approval=None, decisions=(), target=None,
                         robot="idle", robot_events=(), outcome=None, planning=False, capturing=False,
                         scene_problems=(), repairs=(), session_id=None, verifications=(), deviation=None,
                         run_end=None, message="", error=msg)

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



__all__ = ["Workflow", "WorkflowError", "State", "PlanEntry", "Deviation", "Throttle", "PLANNERS", "SECONDS_PER_BOX",
           "AUTH_REFUSED", "scene_problems", "problem_text", "look_again", "Look"]
