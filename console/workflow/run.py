"""The robot run: the approved plan sent on a background thread, each step looked at, the outcome stored.

Audit first: the robot starts once its run is committed, each step goes out
once its `sent` record is committed, a robot event that cannot be committed
stops the run at once (and is retried, in order, until it is: the journal,
console/store/journal.py; no run starts while anything waits there), and a
look after a step that cannot be recorded holds the robot. A held step's look
becomes the current capture (plan again from it, or continue as planned).
One run at a time per database, across consoles: `store.start_run` refuses
while another live console's run is open.
"""
from __future__ import annotations

import threading
import traceback
from typing import TYPE_CHECKING, Any, Callable, Mapping

from shelfpick.perception.scene import Scene

from shelfpick.console.store.journal import JournalStatus, RecordJournal
from shelfpick.console.store.schema import RunConflict
from shelfpick.console.workflow.continuation import continuation, mapped_target
from shelfpick.console.workflow.core import WorkflowCore
from shelfpick.console.workflow.look import Look, look_again
from shelfpick.console.workflow.run_json import outcome_json, perception_summary, step_json
from shelfpick.console.workflow.state import Deviation, RunEnd, RunLock, State, WorkflowError

if TYPE_CHECKING:
    from shelfpick.console.robot.base import RobotDriver, RobotEvent, RobotOutcome


JOURNAL_CLOSE_WAIT = 2.0   # s close() waits for records still waiting in the journal


class RobotRun(WorkflowCore):
    """`execute()`, `stop()` and the run's worker thread."""

    @property
    def journal(self) -> RecordJournal:
        """The run records that wait for the database (made at first use)."""
        with self._lock:
            j = self.__dict__.get("_journal")
            if j is None:
                j = self.__dict__["_journal"] = RecordJournal(self._journal_status)
            return j

    def _journal_status(self, status: JournalStatus | None) -> None:
        """The page says what waits for the database until it is committed (then it says so once)."""
        with self._lock:
            if status is not None:
                self._set(audit=status.text())
            elif self._state.audit and self._state.audit.startswith("database:"):
                self._set(audit=None, message="database: the robot run's records that waited are committed now")

    def _journal_record(self, what: str, fn: Callable[..., Any], *args: Any) -> bool:
        """Commit through the journal (in order, retried until committed); False: not committed yet."""
        try:
            return self.journal.record(what, fn, *args)
        except RuntimeError as exc:       # closed: the console is shutting down
            self._audit_failed(what, exc)
            return False

    def close(self) -> None:
        """Give records that wait for the database a moment, then stop retrying (a restart recovers)."""
        j = self.__dict__.get("_journal")
        if j is not None:
            j.wait_empty(JOURNAL_CLOSE_WAIT)
            j.close()
        super().close()

    def _run_elsewhere(self, action: str) -> None:
        """Refuse `action` while a run of a live console (another process, or this one's last run whose
        records still wait) is open on this database; `store.start_run` checks it again, atomically."""
        active = getattr(self.store, "active_run", None)
        try:
            row = active() if active is not None else None
        except Exception:  # noqa: BLE001 - cannot tell: the start's own check decides
            return
        if row is None:
            return
        if row["owner"] == getattr(self.store, "owner", None):
            self._refuse(f"{action} refused: this console's last run (plan {row['plan_hash']}) is still open "
                         f"in the database: its records wait to be committed")
        self._refuse(f"{action} refused: another console ({row['owner']}) is running plan {row['plan_hash']} of "
                     f"session {row['session_id']} on this database; one run at a time: wait for it to end "
                     f"or press Stop there")

    def execute(self, wait: bool = False) -> State:
        """Send the approved plan to the robot on a background thread, once its start is committed."""
        with self._lock:
            run, st = self._run, self._state
            if run is None or st.approved is None:
                self._refuse("nothing approved: a supervisor must approve a plan first")
            if run.started:
                self._refuse("the robot is already running")
            waiting = self.journal.pending()
            if waiting:
                self._refuse(f"robot not started: {waiting} record(s) of the last run are not yet committed to "
                             f"the database (retrying); nothing is sent until they are")
            if run.decision_id is None or st.approved != run.plan_hash:
                self._refuse("the approval is still being recorded; try again in a moment")
            if (run.session_id != st.session_id or run.gen != self._generation
                    or st.plan_by_hash(run.plan_hash) is None or st.needs_recapture):
                self._release(run)
                self._refuse("the approved plan is not for the current capture")
            run.started = True       # the approval is used up: re-running would re-send steps
            run.scene, run.truth = st.scene, st.truth
            self._set(approved=None, robot="running", robot_events=(), outcome=None, error=None, run_end=None,
                      message=f"robot: starting the {run.entry.plan.planner} plan {run.plan_hash}")
        try:
            from shelfpick.console.robot.base import new_run_id

            done = self._steps_before(run)
            run.robot_run = new_run_id(f"s{run.session_id}-")
            rid = self.store.start_run(run.session_id, run.plan_hash, run.decision_id,
                                       {"sequence": list(run.entry.plan.sequence), "who": run.who,
                                        "robot_run": run.robot_run})
        except Exception as exc:  # noqa: BLE001 - audit first: no committed start, no motion
            msg = exc.args[0] if isinstance(exc, (WorkflowError, RunConflict)) else \
                self._audit_failed("the robot start", exc)
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

    def _steps_before(self, run: RunLock) -> dict[int, str]:
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
            self._journal_record("the stop", self.store.add_robot_event, run.session_id, run.plan_hash, "stop",
                                 None, None, {"who": who, "running": run.started})
        return st

    def _robot_worker(self, run: RunLock, run_id: int, done_before: dict[int, str]) -> None:
        outcome, err = None, None
        try:
            robot = self.robot_factory(run.truth, self.seed)
            seed_history(robot, run.plan_hash, done_before)
            if hasattr(robot, "run_id"):
                robot.run_id = run.robot_run
            if hasattr(robot, "record_sent"):
                robot.record_sent = self._sent_recorder(run)
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

    def _verifier(self, run: RunLock) -> Callable[..., str | None]:
        """After each `done`: look again, compare with the predicted shelf; a reason string holds the robot.

        Runs on the robot's thread before the next step is sent. The record is
        committed before the answer is given (audit first): a verification
        that cannot be recorded, or cannot be made, holds the robot too.
        """
        def verify(step: int, box: str, world: Scene | None = None) -> str | None:
            from shelfpick.console.workflow.verify import unavailable

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
                # the shelf this look saw: the 3D view draws it, step by step (h6, issue 33)
                seen = {"observed": perception.scene} if perception is not None else {}
                self._set(verifications=tuple(run.verifications), message=v.summary(), **seen)
            if v.within:
                return None
            if look.frame is not None and perception is not None:
                run.held = look._replace(verification=v)
            return v.summary()
        return verify

    def _look(self, run: RunLock, step: int, box: str, world: Scene | None) -> Look:
        """The look after `step`: the new frame compared with the shelf the plan predicted."""
        shelves = run.entry.shelves
        predicted = shelves[step] if step < len(shelves) else None
        removed = run.scene.box(box) if box in run.scene.ids else None
        return look_again(self.source, world, step, box, predicted, run.scene.shelf, self.segmenter,
                          self.tolerance, self.perceive_options, removed)

    def _sent_recorder(self, run: RunLock) -> Callable[[int, str], None]:
        """The driver calls it before a step goes out: the `sent` record is committed, or it raises
        and the step is not sent (nor is any while earlier records wait for the database)."""
        def record_sent(step: int, box: str) -> None:
            if run.stop.is_set():
                raise WorkflowError("the run was stopped")
            if self.journal.pending():
                raise WorkflowError("earlier records of this run wait for the database")
            try:
                self.store.add_robot_event(run.session_id, run.plan_hash, "sent", step, box,
                                           {"run": run.robot_run})
            except Exception as exc:  # noqa: BLE001 - audit first: no record, no motion
                run.stop.set()
                run.audit_failed = (self._audit_failed(f"that step {step + 1} is sent", exc)
                                    + f"; step {step + 1} ({box}) was not sent and the robot was stopped")
                raise
        return record_sent

    def _on_event(self, run: RunLock) -> Callable[[RobotEvent], None]:
        def on_event(ev: RobotEvent) -> None:
            detail = dict(ev.detail) if ev.detail else None
            if not self._journal_record(f"the {ev.kind}" + (f" of step {ev.step + 1}" if isinstance(ev.step, int)
                                                             else ""),
                                        self.store.add_robot_event, run.session_id, run.plan_hash, ev.kind,
                                        ev.step, ev.box, detail):
                # audit first: not on record (yet), so no further motion; the journal keeps trying
                run.stop.set()
                if not run.audit_failed:
                    run.audit_failed = (f"database: could not record a robot event ({ev.kind}); the robot was "
                                        f"stopped; the record is retried until it is committed")
            with self._lock:
                events = self._state.robot_events + (ev,)
                step = f" step {ev.step + 1}" if isinstance(ev.step, int) else ""
                self._set(robot_events=events, message=f"robot: {ev.kind}{step}" + (f" ({ev.box})" if ev.box else ""))
        return on_event

    def _finish(self, run: RunLock, run_id: int, outcome: RobotOutcome | None, err: str | None) -> None:
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
        out_doc = outcome_json(outcome, err, run.entry, stop_asked, run.stopped_by)
        if run.verifications:
            out_doc["verified"] = [v.to_json() for v in run.verifications]
            out_doc["held"] = status == "held"
        self._journal_record("the outcome", self.store.set_outcome, run.session_id, out_doc, run_id)
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
                      run_end=run_end(run, status, outcome),
                      error=err if status not in ("stopped", "held") or run.audit_failed else None)

    def _held_capture(self, run: RunLock, status: str, outcome: RobotOutcome | None, msg: str,
                      err: str | None) -> bool:
        """The look that held the robot becomes the current capture: plan again from it, or continue.

        A new session (its images and perceived scene, linked to the held one)
        and, when every box the held plan still has to take was seen, a
        `continue` plan: the rest of the held plan in the new capture's ids,
        which a supervisor may approve (ticking `Accept predicted risk`).
        """
        v, frame, perception, predicted = run.held   # set only with a frame and its perception
        info = {"frame": frame.name, **perception_summary(perception),
                "verification_of": {"session": run.session_id, "plan": run.plan_hash, "step": v.step,
                                    "run": run.robot_run}}
        try:
            sid = self.store.new_session(self._state.source, frame.capture, perception.scene, frame.truth,
                                         perception.overlay, info, labels=perception.masks,
                                         matter=perception.unexplained_labels)
        except Exception as exc:  # noqa: BLE001 - no record, nothing of it can be approved: fall back
            self._audit_failed("the capture taken after the held step", exc)
            return False
        cont = continuation(run.entry, v, perception.scene, run.session_id)
        recorded = False
        if cont is not None:
            recorded = self._record("the continue-as-planned plan", self.store.add_plan, sid, cont.plan,
                                    [r if isinstance(r, Mapping) else step_json(r)
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
                      labels=perception.masks, matter=perception.unexplained_labels, scene=scene, truth=frame.truth, warnings=tuple(perception.warnings),
                      target=mapped_target(run.entry.plan, v, scene), task=None,
                      plans={"continue": cont} if recorded else {}, planning=False, progress=0.0,
                      progress_text="", approved=None, approval=None, decisions=(), robot=status,
                      outcome=outcome, needs_recapture=False, scene_problems=(), repairs=(),
                      deviation=dev, run_end=run_end(run, status, outcome), message=msg, error=v.summary() if status == "held" else err)
        return True


def run_end(run: RunLock, status: str, outcome: RobotOutcome | None) -> RunEnd:
    """What the page says of an ended run: its plan, end state, and where it stopped (held: the step
    whose look held it; else the first step not done)."""
    plan = run.entry.plan
    step = box = None
    if status == "held" and (run.held is not None or run.verifications):
        v = run.held.verification if run.held is not None else run.verifications[-1]
        step, box = v.step, v.box
    elif status != "done" and outcome is not None:
        first = next((s for s in outcome.steps if s.get("status") not in ("done", "skipped")), None)
        if first is not None and isinstance(first.get("step"), int):
            step, box = first["step"], first.get("box")
    return RunEnd(run.planner or plan.planner, run.plan_hash, tuple(plan.sequence), status,
                  tuple(outcome.completed) if outcome is not None else (), step, box,
                  run.stopped_by if status == "stopped" else None)


def seed_history(robot: RobotDriver, plan_hash: str, done: dict[int, str]) -> None:
    """Give the driver the step history of this run: what this session already did, nothing else.

    The workflow owns it: seeded from the database (`store.step_states`, the
    never-re-send that survives a restart) and handed to the driver, which
    keys it by plan hash alone; a new capture with the same sequence is a new
    run, so each run gets a fresh one. A driver without a `history` (the sim
    robot, whose world is new every run) keeps its own.
    """
    if not hasattr(robot, "history"):
        return
    from shelfpick.console.robot.base import StepHistory

    hist = StepHistory()
    for i, box in done.items():
        hist.mark_done(getattr(robot, "name", ""), plan_hash, i, box)
    robot.history = hist



__all__ = ["RobotRun", "run_end", "seed_history"]
