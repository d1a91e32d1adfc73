"""Reference robot-side controller for `shelfpick.robot/1` (docs/robot-protocol.md).

A real TCP server (threaded `socketserver`, one thread per connection plus
one worker per step, so pings are answered while a step runs). A real robot
integration replaces the body of `_perform` with motion commands; everything
else (framing, acks, heartbeats, aborts, duplicate refusal) is what such an
integration needs to get right, and the console's tests run against it.

"Already done" is keyed by the console's run id (`run` in `hello` and each
`step`), the plan hash and the step: a new capture's run of the same plan is
a new run and is executed; the same step twice within one run is refused
with DUPLICATE_STEP. A console that sends no `run` gets the old keying by
plan hash and step.

It can act on a "truth" scene in its own `ShelfSim`: the grasp point it
receives (robot base frame) is mapped back through the inverse shelf-to-robot
transform and the box whose front face is there is pulled out, so what the
console's perception thought and what the shelf holds may disagree, as on a
real shelf. Without a truth scene it just acknowledges and reports done.

One run at a time: from its `hello` until `bye` or the connection closes, a
connection holds the robot for its run; a `hello` of another run on any
other connection is answered `error` `BUSY` (after waiting up to
`claim_wait` seconds for a connection that is just closing), so two
consoles can never drive the robot at once.

Fault injection for tests: refuse given steps, drop the connection after k
completed steps or while step k is in flight, hang (go silent) on a step,
take `ack_delay` seconds before an `ack` and `step_time` seconds per step.

    python -m shelfpick.robotsim --port 9000 [--truth scene.json] [--transform t.json]

It imports nothing of the console: the wire it speaks is `robotsim.wire`.
"""
from __future__ import annotations

import argparse
import logging
import math
import socket
import socketserver
import sys
import threading
import time
from dataclasses import replace
from typing import Any, Iterable

from shelfpick.perception.scene import Scene
from shelfpick.robotsim.transform import Transform
from shelfpick.robotsim.wire import PROTOCOL, FloodError, LineConn, ProtocolError

log = logging.getLogger(__name__)


CLAIM_WAIT = 1.0   # s a hello waits for another connection's run to let go before BUSY


class _Server(socketserver.ThreadingTCPServer):
    allow_reuse_address = True
    daemon_threads = True
    block_on_close = False


class _Handler(socketserver.BaseRequestHandler):
    def handle(self) -> None:
        self.server.controller._serve(self.request)  # type: ignore[attr-defined]


class RobotController:
    """A robot-side server; `url` is what `--robot` takes (`tcp://127.0.0.1:PORT`)."""

    def __init__(self, host: str = "127.0.0.1", port: int = 0, *, truth: Scene | None = None,
                 transform: Transform | None = None, refuse_steps: Iterable[int] = (),
                 drop_after: int | None = None, drop_during: int | None = None,
                 hang_on_step: int | None = None, step_time: float = 0.0, seed: int = 0,
                 name: str = "shelfpick-reference", grasp_tol: float = 0.06, ack_delay: float = 0.0,
                 claim_wait: float = CLAIM_WAIT) -> None:
        self.truth = truth
        self.transform = transform or Transform.identity()
        self.refuse_steps = set(refuse_steps)
        self.drop_after = drop_after
        self.drop_during = drop_during
        self.hang_on_step = hang_on_step
        self.step_time = float(step_time)
        self.ack_delay = float(ack_delay)
        self.claim_wait = float(claim_wait)
        self.seed = int(seed)
        self.name = name
        self.grasp_tol = grasp_tol
        self._lock = threading.Lock()
        self._sim_lock = threading.Lock()
        self._sim: Any = None
        self._received: list[dict] = []
        self._executed: list[tuple[str, int, str]] = []
        self._done_keys: set[tuple[str | None, str, int]] = set()   # (run id, plan hash, step)
        self._n_done = 0
        self._conns: set[socket.socket] = set()
        self._holders: dict[int, str | None] = {}    # connection number -> its run (None: no run id)
        self._n_conns = 0
        self._released = threading.Condition(self._lock)
        self._server = _Server((host, port), _Handler, bind_and_activate=True)
        self._server.controller = self  # type: ignore[attr-defined]
        self._thread: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle
    @property
    def address(self) -> tuple[str, int]:
        host, port = self._server.server_address[:2]
        return str(host), int(port)

    @property
    def url(self) -> str:
        host, port = self.address
        return f"tcp://{host}:{port}"

    def start(self) -> "RobotController":
        self._thread = threading.Thread(target=self._server.serve_forever, kwargs={"poll_interval": 0.05},
                                        name="robot-controller", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
        with self._lock:
            conns = list(self._conns)
        for s in conns:
            try:
                s.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        with self._sim_lock:
            if self._sim is not None:
                self._sim.close()
                self._sim = None

    def __enter__(self) -> "RobotController":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def received(self, kind: str | None = None) -> list[dict]:
        with self._lock:
            return [m for m in self._received if kind is None or m.get("type") == kind]

    @property
    def executed(self) -> list[tuple[str, int, str]]:
        """(plan hash, step, box) for every step this robot carried out, in order."""
        with self._lock:
            return list(self._executed)

    def world(self) -> Scene | None:
        """The truth scene as the robot left it (present boxes, current poses)."""
        with self._sim_lock:
            if self._sim is None:
                return self.truth
            base = {b.id: b for b in self._sim.scene.boxes}
            return self._sim.scene.with_boxes(replace(base[i], position=tuple(p), orientation=tuple(q))
                                              for i, (p, q) in self._sim.poses().items())

    # ------------------------------------------------------------------ one connection
    def active_runs(self) -> list[str | None]:
        """The runs that hold the robot now (one at most, or several connections of one run)."""
        with self._lock:
            return list(self._holders.values())

    def _claim(self, state: dict, run: str | None) -> str | None:
        """Hold the robot for this connection's run; None, or which other run holds it (BUSY)."""
        me = state["conn"]
        deadline = time.monotonic() + self.claim_wait
        with self._lock:
            while True:
                others = {r for c, r in self._holders.items() if c != me}
                if not others or (run is not None and others == {run}):
                    self._holders[me] = run
                    return None
                left = deadline - time.monotonic()
                if left <= 0:
                    return ", ".join(sorted(str(r) if r is not None else "(a run without id)" for r in others))
                self._released.wait(min(left, 0.05))   # a connection that is just closing lets go

    def _let_go(self, state: dict) -> None:
        with self._lock:
            if state["conn"] in self._holders:
                del self._holders[state["conn"]]
                self._released.notify_all()

    def _serve(self, sock: socket.socket) -> None:
        with self._lock:
            self._conns.add(sock)
            self._n_conns += 1
            number = self._n_conns
        conn = LineConn(sock)
        state = {"hung": False, "busy": False, "abort": None, "step": None, "closed": False, "run": None,
                 "conn": number}
        try:
            while not state["closed"]:
                try:
                    msg = conn.recv(0.1)
                except (ConnectionError, OSError):
                    break
                except ProtocolError as exc:
                    self._send(conn, state, {"type": "error", "code": "BAD_REQUEST", "message": str(exc)})
                    if isinstance(exc, FloodError):
                        break  # past a cap: the peer is broken or hostile, hang up (a running step stops)
                    continue
                if msg is None:
                    continue
                with self._lock:
                    self._received.append(msg)
                if state["hung"]:
                    continue  # a robot that went silent: reads, never answers
                self._dispatch(conn, state, msg)
        finally:
            if state["abort"] is not None:
                state["abort"].set()  # link gone: a real robot stops the motion safely
            self._let_go(state)
            with self._lock:
                self._conns.discard(sock)
            conn.close()

    def _send(self, conn: LineConn, state: dict, msg: dict) -> None:
        if state["closed"] or state["hung"]:
            return
        try:
            conn.send(msg)
        except OSError:
            state["closed"] = True

    def _dispatch(self, conn: LineConn, state: dict, msg: dict) -> None:
        kind = msg["type"]
        if kind == "hello":
            if msg.get("protocol") != PROTOCOL:
                self._send(conn, state, {"type": "error", "code": "BAD_REQUEST",
                                         "message": f"unsupported protocol {msg.get('protocol')!r}"})
                return
            if "run" in msg and not _run_id_ok(msg["run"]):
                self._send(conn, state, {"type": "error", "code": "BAD_REQUEST",
                                         "message": f"run must be a string of 1-{MAX_RUN_ID} characters"})
                return
            holder = self._claim(state, msg.get("run"))
            if holder is not None:
                self._send(conn, state, {"type": "error", "code": "BUSY",
                                         "message": f"another run is active on this robot (run {holder}); "
                                                    f"one run at a time"})
                return
            state["run"] = msg.get("run")
            self._send(conn, state, {"type": "hello", "protocol": PROTOCOL, "robot": self.name,
                                     "executes": "truth-sim" if self.truth is not None else "acknowledge"})
        elif kind == "ping":
            self._send(conn, state, {"type": "pong", "seq": msg.get("seq")})
        elif kind == "pong":
            pass
        elif kind == "step":
            self._on_step(conn, state, msg)
        elif kind == "abort":
            if state["busy"] and state["abort"] is not None:
                state["abort"].set()  # the worker answers `aborted` (or `done` if it already finished)
            else:  # nothing running; say whether that step had already finished
                key = (msg.get("run", state["run"]), msg.get("plan"), msg.get("step"))
                with self._lock:
                    finished = key in self._done_keys
                self._send(conn, state, {"type": "aborted", "plan": msg.get("plan"), "step": msg.get("step"),
                                         "completed": finished})
        elif kind == "bye":
            state["closed"] = True
            self._let_go(state)
        else:
            self._send(conn, state, {"type": "error", "code": "BAD_REQUEST",
                                     "message": f"unknown message type {kind!r}"})

    def _on_step(self, conn: LineConn, state: dict, msg: dict) -> None:
        plan, step, box = msg.get("plan"), msg.get("step"), msg.get("box")
        grasp = msg.get("grasp") if isinstance(msg.get("grasp"), dict) else {}
        problem = None
        if not isinstance(plan, str) or not isinstance(step, int) or isinstance(step, bool) or not isinstance(box, str):
            problem = "step needs string 'plan', integer 'step', string 'box'"
        elif not _vec3(grasp.get("point")) or not _vec3(grasp.get("approach")):
            problem = "step needs grasp.point and grasp.approach as 3 numbers"
        elif not isinstance(msg.get("pull_distance"), (int, float)) or not 0 < msg["pull_distance"] < 2.0:
            problem = f"pull_distance must be in (0, 2) m, got {msg.get('pull_distance')!r}"
        elif "run" in msg and not _run_id_ok(msg["run"]):
            problem = f"run must be a string of 1-{MAX_RUN_ID} characters"
        elif state["run"] is not None and msg.get("run", state["run"]) != state["run"]:
            problem = "step names another run than this connection's hello"
        if problem:
            self._send(conn, state, {"type": "error", "plan": plan, "step": step, "code": "BAD_REQUEST",
                                     "message": problem})
            return
        if state["busy"]:
            self._send(conn, state, {"type": "error", "plan": plan, "step": step, "code": "BUSY",
                                     "message": f"step {state['step']} is still running"})
            return
        run = msg.get("run", state["run"])
        with self._lock:
            dup = (run, plan, step) in self._done_keys
        if dup:
            self._send(conn, state, {"type": "error", "plan": plan, "step": step, "code": "DUPLICATE_STEP",
                                     "message": f"step {step} of plan {plan} was already executed in run {run}"})
            return
        if step in self.refuse_steps:
            self._send(conn, state, {"type": "error", "plan": plan, "step": step, "code": "REFUSED",
                                     "message": f"robot refuses step {step} ({box})"})
            return
        if self.hang_on_step == step:
            state["hung"] = True
            return
        if self.ack_delay > 0:
            time.sleep(self.ack_delay)   # a slow robot controller: the console waits for the ack
        self._send(conn, state, {"type": "ack", "plan": plan, "step": step, "box": box})
        abort = threading.Event()
        state["abort"], state["step"], state["busy"] = abort, step, True
        threading.Thread(target=self._run_step, args=(conn, state, {**msg, "run": run}, abort),
                         name=f"robot-step-{step}", daemon=True).start()

    def _run_step(self, conn: LineConn, state: dict, msg: dict, abort: threading.Event) -> None:
        plan, step, box = msg["plan"], msg["step"], msg["box"]
        if abort.wait(self.step_time) if self.step_time > 0 else abort.is_set():
            state["busy"] = False
            self._send(conn, state, {"type": "aborted", "plan": plan, "step": step})
            return
        try:
            ok, detail = self._perform(msg)
        except Exception as exc:  # noqa: BLE001 - reported to the console, the server keeps running
            log.exception("step failed")
            ok, detail = False, {"code": "INTERNAL", "message": f"{exc.__class__.__name__}: {exc}"}
        state["busy"] = False  # before the reply: the console may send the next step at once
        if not ok:
            self._send(conn, state, {"type": "error", "plan": plan, "step": step,
                                     "code": detail.pop("code", "PICK_FAILED"),
                                     "message": detail.pop("message", ""), "detail": detail})
            return
        with self._lock:
            self._executed.append((plan, step, box))
            self._done_keys.add((msg["run"], plan, step))
            self._n_done += 1
            n_done = self._n_done
        if self.drop_during == step:
            state["closed"] = True  # executed, but the console never hears `done`
            self._let_go(state)
            _hard_close(conn)
            return
        self._send(conn, state, {"type": "done", "plan": plan, "step": step, "box": box, "detail": detail})
        if self.drop_after is not None and n_done >= self.drop_after:
            state["closed"] = True
            self._let_go(state)
            _hard_close(conn)

    # ------------------------------------------------------------------ the robot's work
    def _perform(self, msg: dict) -> tuple[bool, dict]:
        """Carry out one pull. Replace this with motion commands on a real robot."""
        if self.truth is None:
            return True, {"executed": "acknowledged (no truth scene)"}
        from shelfpick.planning.sim import ShelfSim

        inv = self.transform.inverse()
        point = inv.point(msg["grasp"]["point"])
        with self._sim_lock:
            if self._sim is None:
                self._sim = ShelfSim(self.truth)
            sim = self._sim
            base = {b.id: b for b in sim.scene.boxes}
            best, best_d = None, math.inf
            for bid, (p, q) in sim.poses().items():
                d = math.dist(replace(base[bid], position=tuple(p), orientation=tuple(q)).front_center, point)
                if d < best_d:
                    best, best_d = bid, d
            if best is None or best_d > self.grasp_tol:
                return False, {"code": "NO_BOX_AT_GRASP",
                               "message": f"no box front face within {self.grasp_tol} m of the grasp point "
                                          f"{[round(c, 3) for c in point]} (shelf frame)"}
            res = sim.remove(best, seed=self.seed * 1000 + int(msg["step"]))
        detail = res.to_json()
        detail.pop("box", None)  # the robot's own name for the box; the console's id is in the step
        detail["true_box"] = best
        if not res.extracted:
            return False, {"code": "PICK_FAILED", "message": f"box did not come out ({res.note or 'stuck'})",
                           **detail}
        return True, detail


MAX_RUN_ID = 200  # characters of a run id


def _run_id_ok(v: Any) -> bool:
    return isinstance(v, str) and 0 < len(v) <= MAX_RUN_ID


def _vec3(v: Any) -> bool:
    return (isinstance(v, list) and len(v) == 3
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v))


def _hard_close(conn: LineConn) -> None:
    try:
        conn.sock.shutdown(socket.SHUT_RDWR)
    except OSError:
        pass


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m shelfpick.robotsim", description=__doc__.split("\n\n")[0])
    ap.add_argument("--host", default="127.0.0.1")
    ap.add_argument("--port", type=int, default=9000)
    ap.add_argument("--truth", help="scene JSON the robot acts on in its own simulation")
    ap.add_argument("--transform", help="shelf-to-robot transform JSON (as given to the console)")
    ap.add_argument("--step-time", type=float, default=1.0, help="seconds per step (default 1)")
    ap.add_argument("--ack-delay", type=float, default=0.0, help="seconds before each ack (default 0)")
    ap.add_argument("--refuse", type=int, action="append", default=[], help="refuse this step index")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    truth = Scene.load(args.truth) if args.truth else None
    transform = Transform.load(args.transform) if args.transform else None
    ctl = RobotController(args.host, args.port, truth=truth, transform=transform, refuse_steps=args.refuse,
                          step_time=args.step_time, seed=args.seed, ack_delay=args.ack_delay).start()
    print(f"robot controller listening on {ctl.url} ({'truth sim' if truth else 'acknowledge only'})", flush=True)
    try:
        while True:
            time.sleep(1)
    except KeyboardInterrupt:
        pass
    finally:
        ctl.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
