"""One run at a time per database and per robot, across processes (issue 30, item 5).

Two console processes on one SQLite file and one robot (the reference controller on a real TCP
socket): while the first one's step runs, the second one's execute is refused by the database's
run row and nothing of it reaches the robot; once the first run is stopped, the second one runs.
The robot side holds its own lock: two drivers on two connections, one run goes, the other is
answered BUSY before any step.
"""
from __future__ import annotations

import queue
import signal
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from shelfpick.console.robot.tcp import TcpRobot, Timeouts
from shelfpick.console.robot.base import StepHistory
from shelfpick.planning.plan import Plan
from shelfpick.robotsim.controller import RobotController
from shelfpick.robotsim.wire import LineConn
from safety_kit import CONSOLE_RUN, fault
from test_robot_tcp import row_scene

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent


SECOND = textwrap.dedent("""
    import sys, time
    sys.path[:0] = [{root!r}, {here!r}]
    from test_workflow import CodeShelfSource, small_scene, PASS
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow, WorkflowError
    from shelfpick.console.robot.drivers import open_robot
    store = SessionStore({db!r})
    url = {robot!r}
    wf = Workflow(CodeShelfSource(small_scene()), store,
                  lambda truth, seed: open_robot(url, truth=truth, seed=seed), PASS, samples=2)
    def attempt(tag):
        wf.capture()
        wf.plan("clear", wait=True)
        try:
            wf.approve(wf.state.plans["physics"].hash, PASS, "bob")
            wf.execute(wait=True)
            print(tag, "RAN", wf.state.robot, flush=True)
        except WorkflowError as exc:
            print(tag, "REFUSED", str(exc).replace(chr(10), " "), flush=True)
    print("PLANNING", flush=True)
    sys.stdin.readline()            # the first console's step is running now
    attempt("FIRST")
    sys.stdin.readline()            # the first console's run has ended now
    attempt("AGAIN")
    wf.close()
    store.close()
""")


class Proc:
    def __init__(self, code: str, err: Path, stdin: bool = False) -> None:
        with err.open("w") as err_out:
            self.proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=err_out,
                                         stdin=subprocess.PIPE if stdin else None, text=True, cwd=ROOT)
        self.err, self.seen = err, []
        self.lines: queue.Queue[str] = queue.Queue()
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
        raise AssertionError(f"no {prefix!r} within {timeout} s; stdout {self.seen!r}; "
                             f"stderr {self.err.read_text()[-3000:]}")

    def say(self, text: str = "go") -> None:
        self.proc.stdin.write(text + "\n")
        self.proc.stdin.flush()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait(10)


@pytest.mark.slow        # ~110 s on 2 cores: two consoles capture and plan twice between them
def test_two_consoles_on_one_database_and_one_robot_never_run_at_once(tmp_path):
    db = tmp_path / "shared.sqlite"
    with RobotController(step_time=30.0) as ctl:
        robot = ctl.url + "?heartbeat=0.2&heartbeat_timeout=5"
        a = Proc(CONSOLE_RUN.format(root=str(ROOT), here=str(HERE), db=str(db), robot=robot), tmp_path / "a.txt")
        b = Proc(SECOND.format(root=str(ROOT), here=str(HERE), db=str(db), robot=robot), tmp_path / "b.txt",
                 stdin=True)
        try:
            a.wait_for("READY", 120)                        # console A: step 1 acknowledged, 30 s to go
            b.wait_for("PLANNING", 60)
            fault()
            b.say()
            refused = b.wait_for("FIRST", 120)
            hellos_during_a = len(ctl.received("hello"))
            steps_during_a = [(m["run"], m["step"]) for m in ctl.received("step")]
            a.proc.send_signal(signal.SIGTERM)               # A's run is stopped, its console closes
            assert a.proc.wait(60) == 143, a.err.read_text()[-3000:]
            b.say()
            again = b.wait_for("AGAIN", 120)
            assert b.proc.wait(60) == 0, b.err.read_text()[-3000:]
        finally:
            a.kill()
            b.kill()
        runs = [m["run"] for m in ctl.received("hello")]
        steps = [(m["run"], m["step"]) for m in ctl.received("step")]
    assert refused.startswith("FIRST REFUSED approval refused:"), refused   # execute would refuse too
    assert "another console" in refused and "one run at a time" in refused, refused
    assert hellos_during_a == 1 and len(steps_during_a) == 1    # nothing of B reached the robot
    assert again.startswith("AGAIN RAN"), again              # the lock is gone with A's run
    assert len(runs) == 2 and runs[0] != runs[1] and steps[0] == (runs[0], 0) and steps[1] == (runs[1], 0)


def test_the_robot_refuses_a_second_run_while_one_is_active_on_any_connection():
    """Two drivers (as two consoles on two databases would be) on two connections: the robot
    answers the second one's hello BUSY, no step of it is sent; after the first run ends, a third
    run is served."""
    plan = Plan("clear", None, "physics", ("b0", "b1"))
    fast = Timeouts(connect=2.0, ack=2.0, step=20.0, heartbeat_interval=0.1, heartbeat_timeout=2.0, abort=1.0)
    with RobotController(step_time=1.0) as ctl:
        host, port = ctl.address
        first = TcpRobot(host, port, timeouts=fast, history=StepHistory())
        second = TcpRobot(host, port, timeouts=fast, history=StepHistory())
        outs: dict[str, object] = {}
        t = threading.Thread(target=lambda: outs.update(
            first=first.execute(plan, row_scene(), lambda e: None, threading.Event())), daemon=True)
        t.start()
        end = time.monotonic() + 10
        while not ctl.received("step") and time.monotonic() < end:
            time.sleep(0.01)
        fault()
        out2 = second.execute(plan, row_scene(), lambda e: None, threading.Event())
        t.join(30)
        third = TcpRobot(host, port, timeouts=fast, history=StepHistory()).execute(
            Plan("clear", None, "physics", ("b2",)), row_scene(), lambda e: None, threading.Event())
        steps = [(m["run"], m["step"]) for m in ctl.received("step")]
        end = time.monotonic() + 5                   # the robot lets go once it reads the last `bye`
        while ctl.active_runs() and time.monotonic() < end:
            time.sleep(0.01)
        active_after = ctl.active_runs()
    out1 = outs["first"]
    assert out1.ok, out1.error
    assert not out2.ok and "BUSY" in out2.error and "one run at a time" in out2.error, out2.error
    assert all(s["status"] == "not_sent" for s in out2.steps)
    assert second.last_run_id not in {r for r, _ in steps}     # no step of the refused run was sent
    assert third.ok and active_after == []


def test_one_run_may_reconnect_but_another_run_waits_for_it_to_let_go():
    """A reconnect of the run that holds the robot is served (the duplicate check guards its
    steps); another run is BUSY until the holder says bye or its connection closes."""
    with RobotController(claim_wait=0.2) as ctl:
        def hello(run: str) -> tuple[LineConn, dict]:
            import socket

            conn = LineConn(socket.create_connection(ctl.address, timeout=2))
            conn.send({"type": "hello", "protocol": "shelfpick.robot/1", "plan": "p", "steps": 1, "run": run})
            return conn, conn.recv(2)

        a, ra = hello("run-A")
        a2, ra2 = hello("run-A")
        b, rb = hello("run-B")
        assert ra["type"] == "hello" and ra2["type"] == "hello"
        assert rb["type"] == "error" and rb["code"] == "BUSY" and "run-A" in rb["message"]
        a.send({"type": "bye", "plan": "p", "run": "run-A"})
        a2.close()
        time.sleep(0.3)
        c, rc = hello("run-C")
        assert rc["type"] == "hello", rc
        assert ctl.active_runs() == ["run-C"]
        for conn in (a, b, c):
            conn.close()


def test_the_database_holds_one_open_run_of_a_live_console(tmp_path):
    """Two stores (two consoles: each holds its own owner lock) on one file: the second start is
    refused while the first console's run is open, allowed once it ended, and a dead console's
    open run (its store closed without an outcome: kill -9) does not block anyone."""
    from shelfpick.console.store.sessions import RunConflict, SessionStore
    from test_store import tiny_capture, tiny_scene

    db = tmp_path / "one.sqlite"
    a, b = SessionStore(db), SessionStore(db)
    try:
        sa = a.new_session("t", tiny_capture(), tiny_scene(), None, None)
        sb = b.new_session("t", tiny_capture(), tiny_scene(), None, None)
        ra = a.start_run(sa, "ha", None, {})
        assert b.active_run()["id"] == ra
        with pytest.raises(RunConflict, match="another console .* is running plan ha of session"):
            b.start_run(sb, "hb", None, {})
        with pytest.raises(RunConflict, match="this console is running plan ha"):
            a.start_run(sb, "hb", None, {})
        a.set_outcome(sa, {"ok": True}, ra)
        rb = b.start_run(sb, "hb", None, {})          # the first run ended: the next one may start
        b.close()                                      # console b dies with its run open
        c = SessionStore(db)
        try:
            assert c.active_run() is None
            sc = c.new_session("t", tiny_capture(), tiny_scene(), None, None)
            assert c.start_run(sc, "hc", None, {}) > rb
        finally:
            c.close()
    finally:
        a.close()
        b.close()


def test_consoles_opening_one_new_database_at_once_all_open_it(tmp_path):
    """Two consoles started at the same moment on a new --db (the two-console test above met it):
    one had made the file and not yet committed its schema, so the other was refused as 'not a
    shelfpick session database', or 'locked' by SQLite's journal-mode switch (9 of 50 rounds of 4
    before). Each round: 4 stores open one new file at once; every one must open it."""
    from shelfpick.console.store.sessions import SessionStore, StoreError

    refused: list[str] = []
    for r in range(30):
        db = tmp_path / f"new{r}.sqlite"
        start = threading.Barrier(4)
        stores: list[SessionStore] = []

        def open_it() -> None:
            start.wait()
            try:
                stores.append(SessionStore(db))
            except StoreError as exc:
                refused.append(str(exc))
        threads = [threading.Thread(target=open_it) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
        for s in stores:
            s.close()
    assert refused == []
