"""Shared parts of the console safety tests: a tally of faults, an honest TCP robot peer, a blocking
camera, and a robot that counts how many runs move at once."""
from __future__ import annotations

import json
import textwrap
import socket
import threading
import time
from typing import Any, Callable

# faults injected, robot steps that ran unapproved or unrecorded (0), stops that did not stop (0)
TALLY = {"faults": 0, "unapproved": 0, "unrecorded": 0, "stops": 0, "stops_not_stopping": 0}
# the TCP driver against hostile peers (test_faults_robot.py): "unapproved" counts steps sent after a fault
ROBOT_TALLY = {"faults": 0, "unapproved": 0, "unrecorded": 0, "stops": 0, "stops_not_stopping": 0}


def fault(n: int = 1) -> None:
    TALLY["faults"] += n


def judge_session(store: Any, sid: int, moved: list[tuple[str, int]]) -> None:
    """Every step a robot performed in session `sid` ((plan, step) pairs) must have an approval and
    a committed start before it, and its ack committed: else it counts as unapproved or unrecorded."""
    rec = store.load_session(sid)
    approved = {d["plan_hash"] for d in rec.decisions if d["decision"] == "approve"}
    started = {e["plan_hash"] for e in rec.robot_events if e["kind"] == "start"}
    acked = {(e["plan_hash"], e["step"]) for e in rec.robot_events if e["kind"] == "ack"}
    for plan, step in moved:
        if plan not in approved:
            TALLY["unapproved"] += 1
        if plan not in started or (plan, step) not in acked:
            TALLY["unrecorded"] += 1


def judge_stop(stopped: bool) -> None:
    TALLY["stops"] += 1
    if not stopped:
        TALLY["stops_not_stopping"] += 1


class HonestPeer:
    """A robot-side TCP server that does every step it is sent (ack, then done), or follows `script`
    per connection: script(conn_index, step) -> "ok" | "refuse" | "drop_after_ack"."""

    def __init__(self, script: Callable[[int, int], str] | None = None, step_time: float = 0.0) -> None:
        self.script = script or (lambda c, s: "ok")
        self.step_time = step_time
        self.message = "not now"                        # the text of a refusal (may carry markup)
        self.steps: list[tuple[int, str, int]] = []     # (connection, plan, step) as received
        self.performed: list[tuple[str, int]] = []      # (plan, step) acknowledged = the robot moved
        self.lock = threading.Lock()
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.url = f"tcp://127.0.0.1:{self.srv.getsockname()[1]}?heartbeat=0.2&heartbeat_timeout=2"
        self.conns = 0
        self.closed = False
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while not self.closed:
            try:
                sock, _ = self.srv.accept()
            except OSError:
                return
            with self.lock:
                idx, self.conns = self.conns, self.conns + 1
            threading.Thread(target=self._serve, args=(sock, idx), daemon=True).start()

    def _serve(self, sock: socket.socket, idx: int) -> None:
        f = sock.makefile("rwb")

        def send(m: dict) -> None:
            f.write((json.dumps(m) + "\n").encode())
            f.flush()
        try:
            for line in f:
                if not line.strip():
                    continue
                m = json.loads(line)
                if m["type"] == "hello":
                    send({"type": "hello", "protocol": "shelfpick.robot/1", "robot": "honest"})
                elif m["type"] == "ping":
                    send({"type": "pong", "seq": m.get("seq")})
                elif m["type"] == "abort":
                    send({"type": "aborted", "plan": m["plan"], "step": m.get("step"), "completed": False})
                elif m["type"] == "step":
                    with self.lock:
                        self.steps.append((idx, m["plan"], m["step"]))
                    what = self.script(idx, m["step"])
                    key = {"plan": m["plan"], "step": m["step"], "box": m["box"]}
                    if what == "refuse":
                        send({"type": "error", **key, "code": "REFUSED", "message": self.message})
                        continue
                    send({"type": "ack", **key})
                    with self.lock:
                        self.performed.append((m["plan"], m["step"]))
                    if what == "drop_after_ack":
                        return
                    time.sleep(self.step_time)
                    send({"type": "done", **key, "detail": {}})
        except (OSError, ValueError):
            pass
        finally:
            try:
                sock.close()
            except OSError:
                pass

    def close(self) -> None:
        self.closed = True
        self.srv.close()


class BlockingSource:
    """Wraps a source; while `gate` is clear its capture waits (a slow camera)."""

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.name = inner.name
        self.gate = threading.Event()
        self.gate.set()
        self.entered = threading.Event()

    def capture(self):
        self.entered.set()
        self.gate.wait(30)
        return self.inner.capture()


class CountingRobots:
    """A robot factory around the sim robot that records how many runs move at once."""

    def __init__(self, delay: float = 0.3) -> None:
        self.delay = delay
        self.active = 0
        self.max_active = 0
        self.runs = 0
        self.moved: list[tuple[str, int]] = []
        self.lock = threading.Lock()

    def __call__(self, truth: Any, seed: int) -> Any:
        from shelfpick.console.robot.drivers import open_robot

        inner = open_robot(f"sim?delay={self.delay}", truth=truth, seed=seed)
        outer = self

        class Counting:
            name = "counting-sim"

            def execute(self, plan, scene, on_event, stop):
                with outer.lock:
                    outer.active += 1
                    outer.runs += 1
                    outer.max_active = max(outer.max_active, outer.active)
                h = plan.content_hash()

                def ev(e):
                    if e.kind == "ack":
                        with outer.lock:
                            outer.moved.append((h, e.step))
                    on_event(e)
                try:
                    return inner.execute(plan, scene, ev, stop)
                finally:
                    with outer.lock:
                        outer.active -= 1
        return Counting()


# A real console process (`cmd_console.build` + `serve`) on a small shelf that captures, plans,
# is approved and starts a run on ROBOT, printing READY once step 1 is acknowledged (or FAILED):
# the run-integrity tests kill, interrupt or race it. Format with root, here, db, robot.
CONSOLE_RUN = textwrap.dedent("""
    import sys, threading, time
    sys.path[:0] = [{root!r}, {here!r}]
    from test_workflow import CodeShelfSource, small_scene, PASS
    from shelfpick.console import cmd_console
    from shelfpick.console.cli import build_parser, configure_logging
    args = build_parser().parse_args(["console", "--port", "0", "--db", {db!r}, "--robot", {robot!r},
                                      "--samples", "2", "--no-capture", "--supervisor-passphrase", PASS])
    configure_logging("console", 0)
    parts = cmd_console.build(args)
    wf = parts[1]
    wf.source = CodeShelfSource(small_scene())
    def drive():
        try:
            wf.capture()
            wf.plan("clear", wait=True)
            wf.approve(wf.state.plans["physics"].hash, PASS, "sue")
            wf.execute()
            while not any(e.kind == "ack" for e in wf.state.robot_events):
                time.sleep(0.01)
            print("READY", wf.state.session_id, flush=True)   # step 1 acknowledged; it takes 30 s
        except BaseException as exc:
            print("FAILED", repr(exc), flush=True)
            raise
    threading.Thread(target=drive, daemon=True).start()
    sys.exit(cmd_console.serve(parts, args))
""")
