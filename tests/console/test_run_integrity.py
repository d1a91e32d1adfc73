"""The robot run's records when the database is locked at the worst moment (issue 30, item 1).

Real parts: a console workflow in its own process on a real SQLite file, the reference robot
controller on a real TCP socket on 127.0.0.1, and this test process holding a write lock on the
database (longer than the console store's timeout) exactly while the first `ack` arrives. The
robot is made to take 0.6 s before its `ack`, so the lock is taken after the step's `sent` record
is committed and before the `ack` comes: the timing does not depend on luck.
"""
from __future__ import annotations

import queue
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

from shelfpick.robotsim.controller import RobotController
from safety_kit import fault, judge_session

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent
STORE_TIMEOUT = 0.5      # the console store's busy timeout in the child (s); the lock is held far longer

CHILD = textwrap.dedent("""
    import os, sys, threading, time
    sys.path[:0] = [{root!r}, {here!r}]
    from test_workflow import CodeShelfSource, small_scene, PASS
    said = threading.Lock()
    def say(*words):                 # the listener's thread and this one print: whole lines only,
        line = " ".join(map(str, words)) + chr(10)   # each one os.write to the pipe (atomic under
        with said:                   # PIPE_BUF), past sys.stdout's buffer: once, under load, two
            os.write(1, line.encode())   # print()ed lines came joined ("ROBOT idleEXECUTE 1 ...")
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from shelfpick.console.robot.drivers import open_robot
    store = SessionStore({db!r}, timeout={timeout!r})
    url = {url!r}
    wf = Workflow(CodeShelfSource(small_scene()), store,
                  lambda truth, seed: open_robot(url, truth=truth, seed=seed), PASS, samples=2)
    seen = set()
    def show(s):
        for line in (f"AUDIT {{s.audit}}" if s.audit else None, f"ROBOT {{s.robot}}"):
            if line and line not in seen:
                seen.add(line)
                say(line.replace(chr(10), " "))
    wf.add_listener(show)
    wf.capture()
    wf.plan("clear", wait=True)
    h = wf.state.plans["physics"].hash
    wf.approve(h, PASS, "sue")
    say("EXECUTE", wf.state.session_id, h)
    wf.execute()
    wf.wait_robot(120)
    say("ENDED", wf.state.robot)
    pending = lambda: wf.journal.pending() if hasattr(wf, "journal") else 0   # (a console without one)
    end = time.monotonic() + 60
    while pending() and time.monotonic() < end:
        time.sleep(0.05)
    say("FLUSHED", pending())
    time.sleep(0.5)
    say("FINAL AUDIT", wf.state.audit)
    wf.close()
    store.close()
""")


class Child:
    """A console workflow process; its stdout lines arrive on a queue (read by a thread)."""

    def __init__(self, db: Path, url: str, err: Path) -> None:
        code = CHILD.format(root=str(ROOT), here=str(HERE), db=str(db), url=url, timeout=STORE_TIMEOUT)
        with err.open("w") as err_out:
            self.proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=err_out,
                                         text=True, cwd=ROOT)
        self.err = err
        self.lines: queue.Queue[str] = queue.Queue()
        self.seen: list[str] = []
        threading.Thread(target=lambda: [self.lines.put(x.rstrip("\n")) for x in self.proc.stdout],
                         daemon=True).start()

    def wait_for(self, prefix: str, timeout: float) -> str:
        for line in self.seen:        # a line another wait read past (threads print in any order)
            if line.startswith(prefix):
                return line
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            try:
                line = self.lines.get(timeout=0.2)
            except queue.Empty:
                if self.proc.poll() is not None and self.lines.empty():
                    break
                continue
            self.seen.append(line)
            if line.startswith(prefix):
                return line
        raise AssertionError(f"no {prefix!r} from the console within {timeout} s; stdout {self.seen!r}; "
                             f"stderr {self.err.read_text()[-3000:]}")

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)


class SpyController(RobotController):
    """The reference controller, noting for each step it receives whether its `sent` record was
    already committed in the console's database at that moment."""

    def __init__(self, db: Path, **kw) -> None:
        super().__init__(**kw)
        self.db = db
        self.sent_on_record: list[tuple[int, bool]] = []

    def _on_step(self, conn, state, msg) -> None:
        with sqlite3.connect(f"{self.db.resolve().as_uri()}?mode=ro", uri=True) as ro:
            row = ro.execute("SELECT 1 FROM robot_events WHERE kind='sent' AND plan_hash=? AND step=?",
                             (msg.get("plan"), msg.get("step"))).fetchone()
        self.sent_on_record.append((msg.get("step"), row is not None))
        super()._on_step(conn, state, msg)


def lock_when_sent(db: Path, child: Child, timeout: float = 120) -> sqlite3.Connection:
    """Wait for the first `sent` record, then hold the database's write lock (another process).

    A console that records no `sent` (the code before issue 30) is locked 0.3 s after its run's
    `start` instead, still well before the robot's `ack` (0.6 s after the step arrives)."""
    child.wait_for("EXECUTE", timeout)
    end, started = time.monotonic() + 30, None
    while time.monotonic() < end:
        with sqlite3.connect(db) as ro:
            kinds = {k for (k,) in ro.execute("SELECT kind FROM robot_events WHERE kind IN ('start', 'sent')")}
        if "sent" in kinds:
            break
        if "start" in kinds:
            started = started or time.monotonic()
            if time.monotonic() - started > 0.3:
                break
        time.sleep(0.01)
    else:
        raise AssertionError("the run was not started")
    other = sqlite3.connect(db, timeout=5, isolation_level=None)
    other.execute("BEGIN IMMEDIATE")
    return other


def events(db: Path, sid: int) -> list[tuple[str, int | None]]:
    with sqlite3.connect(db) as c:
        return [(k, s) for k, s in c.execute("SELECT kind, step FROM robot_events WHERE session_id=? "
                                             "AND kind NOT IN ('auth_refused', 'note') ORDER BY id", (sid,))]


def test_an_ack_that_meets_a_locked_database_is_committed_once_it_is_free(tmp_path):
    """The lock outlasts the store's timeout as the `ack` arrives: the run stops (no further step goes
    out), the page says the records wait, and once the lock is gone the `ack`, the `done` and the
    outcome are committed in order: the session ends `stopped`, not `executing` for ever."""
    from shelfpick.console.store.sessions import SessionStore

    db = tmp_path / "run.sqlite"
    with SpyController(db, ack_delay=0.6, step_time=0.05) as ctl:
        child = Child(db, ctl.url + "?heartbeat=0.2&heartbeat_timeout=5", tmp_path / "err.txt")
        try:
            other = lock_when_sent(db, child)
            fault()
            try:
                audit = child.wait_for("AUDIT database:", 30)     # the page says what waits, and why
                assert "not yet committed" in audit and "retrying" in audit, audit
                assert child.wait_for("ENDED", 30) == "ENDED stopped"
                time.sleep(2 * STORE_TIMEOUT + 1.0)                # it keeps trying: still locked here
            finally:
                other.rollback()
                other.close()
            assert child.wait_for("FLUSHED", 60) == "FLUSHED 0"
            final = child.wait_for("FINAL AUDIT", 10)
            assert child.proc.wait(30) == 0, child.err.read_text()[-3000:]
        finally:
            child.kill()
        steps = [m["step"] for m in ctl.received("step")]
        sent_on_record = list(ctl.sent_on_record)
        moved = [(h, s) for h, s, _ in ctl.executed]
    assert final == "FINAL AUDIT None", child.seen            # the warning goes once all is on record
    assert steps == [0] and sent_on_record == [(0, True)]    # one step, and it was on record first
    sid = int(next(x for x in child.seen if x.startswith("EXECUTE")).split()[1])
    kinds = events(db, sid)
    assert kinds[:4] == [("start", None), ("sent", 0), ("ack", 0), ("done", 0)], kinds
    store = SessionStore(db, readonly=True)
    rec = store.load_session(sid)
    assert rec.status == "stopped" and rec.outcome is not None and not rec.outcome["ok"]
    assert rec.outcome["steps"][0]["status"] == "done" and rec.outcome["completed"] == [rec.outcome["sequence"][0]]
    assert all(s["status"] != "done" for s in rec.outcome["steps"][1:])
    with sqlite3.connect(db) as c:
        assert c.execute("SELECT COUNT(*) FROM runs WHERE ended IS NULL").fetchone()[0] == 0
    judge_session(store, sid, moved)
    store.close()


def test_a_console_that_dies_with_its_ack_unrecorded_leaves_the_step_unknown(tmp_path):
    """kill -9 while the `ack` still waits for the locked database: the restart calls the sent step's
    outcome unknown and tells the operator to look at the shelf, never `not_sent`."""
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    db = tmp_path / "dead.sqlite"
    with RobotController(ack_delay=0.6, step_time=0.05) as ctl:
        child = Child(db, ctl.url + "?heartbeat=0.2&heartbeat_timeout=5", tmp_path / "err.txt")
        try:
            other = lock_when_sent(db, child)
            fault()
            try:
                child.wait_for("ENDED", 30)
                child.kill()                                   # SIGKILL with the ack not on record
            finally:
                other.rollback()
                other.close()
        finally:
            child.kill()
        assert [m["step"] for m in ctl.received("step")] == [0]
    sid = int(next(x for x in child.seen if x.startswith("EXECUTE")).split()[1])
    assert ("ack", 0) not in events(db, sid)                 # the lock kept it out
    store = SessionStore(db)                                  # the restart
    wf = Workflow(None, store, lambda t, s: None, "pw")
    try:
        rec = store.load_session(sid)
        box = rec.outcome["sequence"][0]
        assert rec.status == "interrupted"
        assert rec.outcome["steps"][0]["status"] == "unknown", rec.outcome["steps"]
        assert "look at the shelf" in rec.outcome["steps"][0]["detail"]["reason"]
        assert all(s["status"] == "not_sent" for s in rec.outcome["steps"][1:])
        assert store.step_states(sid, rec.outcome["plan"])[0] == ("unknown", box)
        note = " ".join(wf.state.recovered)
        assert f"step 1 ({box}): outcome unknown, check the shelf" in note, note
        assert "no step was in flight" not in note
    finally:
        wf.close()
        store.close()


def test_a_step_whose_sent_record_cannot_be_committed_is_not_sent():
    """Both drivers ask the console to commit `sent` before a step goes out; a refusal keeps that
    step (and every later one) off the robot."""
    import threading

    from shelfpick.console.robot.drivers import SimRobot
    from shelfpick.console.robot.tcp import TcpRobot, Timeouts
    from shelfpick.console.robot.base import StepHistory
    from shelfpick.planning.plan import Plan
    from test_robot_tcp import row_scene

    plan = Plan("clear", None, "physics", ("b0", "b1", "b2"))
    asked: list[tuple[int, str]] = []

    def record_sent(step: int, box: str) -> None:
        asked.append((step, box))
        if step == 1:
            raise OSError("database is locked")

    with RobotController() as ctl:
        host, port = ctl.address
        robot = TcpRobot(host, port, timeouts=Timeouts(heartbeat_interval=0.1), history=StepHistory())
        robot.record_sent = record_sent
        out = robot.execute(plan, row_scene(), lambda e: None, threading.Event())
        steps = [m["step"] for m in ctl.received("step")]
    assert steps == [0] and asked == [(0, "b0"), (1, "b1")]
    assert [s["status"] for s in out.steps] == ["done", "not_sent", "not_sent"]
    assert "was not sent" in out.error and "database is locked" in out.error

    asked.clear()
    sim = SimRobot(row_scene(), seed=0)
    sim.record_sent = record_sent
    try:
        out = sim.execute(plan, row_scene(), lambda e: None, threading.Event())
    finally:
        sim.close()
    assert asked == [(0, "b0"), (1, "b1")] and out.completed == ("b0",)
    assert [s["status"] for s in out.steps][1:] == ["not_sent", "not_sent"]
