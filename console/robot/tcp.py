"""The TCP robot driver of the wire protocol `shelfpick.robot/1` (docs/robot-protocol.md).

The framing (`LineConn`, its caps and errors) and the shelf-to-robot
`Transform` are shared with the robot side and live in `robotsim.wire` and
`robotsim.transform`; they are re-exported here for the console's users.

One JSON object per line (UTF-8, `\\n` terminated) in each direction over one
TCP connection per plan run. Per step the console sends the box id, the
suction grasp (front-face centre, approach direction, face normal) in the
ROBOT BASE frame, obtained through a configured shelf-to-robot transform, and
the pull distance; the robot answers `ack`, then `done` or `error`. While it
waits the console pings; a robot that stops answering for
`heartbeat_timeout` seconds is treated as gone. A disconnect, a timeout or an
error stops the sequence; steps that were confirmed `done` are remembered per
plan hash and never sent again; a step that was in flight when the link
dropped is `unknown` and blocks that plan for good (a new capture and plan
are needed: the shelf may have changed).

Every run carries a `run` id in `hello` and each `step`: the robot keys "this
step was already done" by run and step, so a new capture's run of the same
plan hash is executed while a repeated step within one run is refused.
"""
from __future__ import annotations

import json
import socket
import threading
import time
from dataclasses import dataclass
from typing import Any, Callable, Mapping
from urllib.parse import parse_qs, urlsplit

from shelfpick.perception.scene import Box, Scene, quat_to_matrix
from shelfpick.planning.plan import Plan
from shelfpick.robotsim.transform import Transform
from shelfpick.robotsim.wire import PROTOCOL, FloodError, LineConn, ProtocolError

from shelfpick.console.robot.base import (RobotError, RobotEvent, RobotOutcome, StepHistory, emit, finish,
                                          new_run_id, query_float, record_before_sending)

MAX_TEXT = 500          # characters of a peer's code/message kept in events and errors
STEP_REPLIES = frozenset({"ack", "done", "error", "aborted"})
DISTRUSTED = ("PROTOCOL",)  # link failures after which an unacknowledged step may have moved
PULL_CLEARANCE = 0.05   # m beyond the shelf's front edge the box's back face is pulled
ERROR_CODES = ("BAD_REQUEST", "REFUSED", "BUSY", "DUPLICATE_STEP", "NO_BOX_AT_GRASP", "PICK_FAILED",
               "ABORTED", "INTERNAL")



def grasp_for(box: Box, scene: Scene, transform: Transform) -> dict:
    """Suction grasp for `box`: front-face centre, approach (+y shelf), face normal, pull distance.

    The gripper moves along `approach` (into the shelf) onto the face, then
    pulls along -approach by `pull_distance`: far enough that the box's back
    face clears the shelf's front edge by PULL_CLEARANCE. An unseen depth
    (`depth_known` false) is taken as reaching the back wall, the worst case.
    """
    r = quat_to_matrix(box.orientation)
    normal_shelf = (-r[0][1], -r[1][1], -r[2][1])      # the box's own -y axis: out of the front face
    back_y = max(c[1] for c in box.corners()) if box.depth_known else scene.shelf.depth
    pull = max(back_y, 0.0) + PULL_CLEARANCE
    rnd = lambda v: [round(float(x), 6) for x in v]  # noqa: E731
    return {"grasp": {"point": rnd(transform.point(box.front_center)),
                      "approach": rnd(transform.direction((0.0, 1.0, 0.0))),
                      "normal": rnd(transform.direction(normal_shelf))},
            "pull_distance": round(pull, 4),
            "box_size": rnd(box.size)}


def step_message(plan_hash: str, step: int, box: Box, scene: Scene, transform: Transform,
                 run: str | None = None) -> dict:
    msg = {"type": "step", "plan": plan_hash, "step": step, "box": box.id, "frame": "robot_base",
           **grasp_for(box, scene, transform)}
    if run is not None:
        msg["run"] = run
    return msg



# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Timeouts:
    """Seconds. `ack`: step sent -> ack; `step`: ack -> done/error; heartbeat: ping period and silence limit."""

    connect: float = 3.0
    ack: float = 2.0
    step: float = 120.0
    heartbeat_interval: float = 0.5
    heartbeat_timeout: float = 3.0
    abort: float = 3.0


class _Lost(Exception):
    """The link is gone or silent; `.code` says how."""

    def __init__(self, code: str, message: str) -> None:
        super().__init__(message)
        self.code = code


class TcpRobot:
    """The `tcp://HOST:PORT` driver: one connection per plan run, line-delimited JSON."""

    def __init__(self, host: str, port: int, transform: Transform | None = None,
                 timeouts: Timeouts | None = None, history: StepHistory | None = None) -> None:
        self.host, self.port = host, int(port)
        self.name = f"tcp://{host}:{self.port}"
        self.transform = transform or Transform.identity()
        # the console's look after each step: verify(step, box, None) -> None (go on) or why to hold
        self.verify: Callable[..., str | None] | None = None
        # the console's record that a step goes out: record_sent(step, box), committed before the
        # step is sent; raising means "not on record": the step is not sent and the run ends
        self.record_sent: Callable[[int, str], None] | None = None
        self.timeouts = timeouts or Timeouts()
        # what this driver's runs did (skipped, never re-sent); the console hands each run its own
        self.history = history if history is not None else StepHistory()
        self.robot_info: dict = {}
        self.run_id: str | None = None       # set by the console (recorded with the run); None: one per run
        self.last_run_id: str | None = None  # the id the last execute() sent

    @classmethod
    def from_spec(cls, spec: str) -> "TcpRobot":
        """`tcp://HOST:PORT?transform=FILE` or `?position=x,y,z&orientation=w,x,y,z`, plus
        `connect_timeout`, `ack_timeout`, `step_timeout`, `heartbeat`, `heartbeat_timeout` (s)."""
        parts = urlsplit(spec)
        try:
            port = parts.port
        except ValueError:
            raise RobotError(f"robot spec {spec!r}: port must be a number 1-65535") from None
        if parts.scheme != "tcp" or not parts.hostname or not port:
            raise RobotError(f"robot spec {spec!r}: expected tcp://HOST:PORT")
        q = parse_qs(parts.query)
        known = {"transform", "position", "orientation", "connect_timeout", "ack_timeout", "step_timeout",
                 "heartbeat", "heartbeat_timeout", "abort_timeout"}
        bad = set(q) - known
        if bad:
            raise RobotError(f"robot spec {spec!r}: unknown option {sorted(bad)[0]!r} "
                             f"(known: {', '.join(sorted(known))})")
        transform = Transform.identity()
        if "transform" in q:
            transform = Transform.load(q["transform"][-1])
        elif "position" in q or "orientation" in q:
            def nums(key: str, n: int, default: list[float]) -> list[float]:
                if key not in q:
                    return default
                try:
                    v = [float(x) for x in q[key][-1].split(",")]
                except ValueError:
                    v = []
                if len(v) != n:
                    raise RobotError(f"robot spec {spec!r}: {key}: expected {n} comma-separated numbers, "
                                     f"got {q[key][-1]!r}")
                return v
            transform = Transform.from_json({"position": nums("position", 3, [0.0, 0.0, 0.0]),
                                             "orientation": nums("orientation", 4, [1.0, 0.0, 0.0, 0.0])},
                                            f"robot spec {spec!r}")
        t = Timeouts()
        t = Timeouts(connect=query_float(q, "connect_timeout", spec, t.connect),
                     ack=query_float(q, "ack_timeout", spec, t.ack),
                     step=query_float(q, "step_timeout", spec, t.step),
                     heartbeat_interval=query_float(q, "heartbeat", spec, t.heartbeat_interval),
                     heartbeat_timeout=query_float(q, "heartbeat_timeout", spec, t.heartbeat_timeout),
                     abort=query_float(q, "abort_timeout", spec, t.abort))
        return cls(parts.hostname, port, transform, t)

    # ------------------------------------------------------------------ the wire
    def _send(self, conn: LineConn, msg: Mapping[str, Any]) -> None:
        try:
            conn.send(msg)
        except OSError as exc:
            raise _Lost("DISCONNECTED", f"connection lost ({exc})") from None

    def _recv(self, conn: LineConn, timeout: float) -> dict | None:
        try:
            return conn.recv(timeout)
        except ConnectionError as exc:
            raise _Lost("DISCONNECTED", str(exc)) from None
        except ProtocolError as exc:
            raise _Lost("PROTOCOL", f"robot broke the protocol: {exc}") from None

    def _wait(self, conn: LineConn, want: set[str], deadline: float, stop: threading.Event | None,
              what: str, expect: tuple[str, int | None, str | None] | None = None) -> dict | str:
        """The next reply, answering pings and sending ours; "stop" when `stop` is set.

        `expect` = (plan hash, step, box) that a step reply (ack, done, error,
        aborted) must carry. A step reply that is not in `want` or carries
        another plan, step or box is a lie or a confusion: _Lost("PROTOCOL").
        Raises _Lost on a disconnect, heartbeat silence or the deadline too.
        """
        t = self.timeouts
        last_heard = time.monotonic()
        next_ping = last_heard + t.heartbeat_interval
        seq = 0
        while True:
            now = time.monotonic()
            if stop is not None and stop.is_set():
                return "stop"
            if now >= deadline:
                raise _Lost("TIMEOUT", f"no {what} within the timeout")
            if now - last_heard > t.heartbeat_timeout:
                raise _Lost("HEARTBEAT", f"robot silent for {t.heartbeat_timeout:g} s (no pong) while waiting "
                            f"for {what}")
            if now >= next_ping:
                seq += 1
                self._send(conn, {"type": "ping", "seq": seq})
                next_ping = now + t.heartbeat_interval
            msg = self._recv(conn, min(0.05, max(deadline - now, 0.0)))
            if msg is None:
                continue
            last_heard = time.monotonic()
            kind = msg["type"]
            if kind == "ping":
                self._send(conn, {"type": "pong", "seq": msg.get("seq")})
            elif kind in STEP_REPLIES or kind == "hello":
                if kind not in want:
                    raise _Lost("PROTOCOL", f"robot sent {kind!r} while the console waited for {what}")
                if expect is not None:
                    check_reply(msg, *expect)
                return msg
            # pong and unknown types: the robot is alive; the line rate cap bounds them

    # ------------------------------------------------------------------ run
    def execute(self, plan: Plan, scene: Scene, on_event: Callable[[RobotEvent], None],
                stop: threading.Event) -> RobotOutcome:
        h = plan.content_hash()
        ep = self.name
        statuses: dict[int, dict] = {}
        earlier = self.history.completed(ep, h)
        unknown = self.history.unknown(ep, h)
        for i, box in earlier.items():
            statuses[i] = {"step": i, "box": box, "status": "skipped",
                           "detail": {"reason": "completed by an earlier run of this plan; not re-sent"}}
        if unknown:
            i, box = min(unknown.items())
            statuses[i] = {"step": i, "box": box, "status": "unknown", "detail": {}}
            return finish(plan, h, statuses, f"step {i + 1} ({box}) of plan {h} was in flight when the link "
                          f"dropped; its outcome is unknown, so this plan is not sent again",
                          self.history, ep)
        todo = [i for i in range(len(plan.sequence)) if i not in earlier]
        if not todo:
            return finish(plan, h, statuses, None, self.history, ep)
        for i in todo:  # every box must be in the scene before anything moves
            scene.require(plan.sequence[i], "plan")
        try:
            sock = socket.create_connection((self.host, self.port), timeout=self.timeouts.connect)
        except OSError as exc:
            msg = f"cannot connect to the robot at {self.name} ({exc})"
            emit(on_event, RobotEvent("disconnected", None, None, {"code": "CONNECT", "message": msg}))
            return finish(plan, h, statuses, msg, self.history, ep)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn = LineConn(sock)
        run = _Run(plan, h, scene, on_event, stop, statuses, self.run_id or new_run_id())
        self.last_run_id = run.run_id
        try:
            error = self._session(conn, run, todo)
        except _Lost as exc:
            error = self._lost(run, exc)
        except OSError as exc:
            emit(on_event, RobotEvent("disconnected", run.current, None,
                                      {"code": "DISCONNECTED", "message": str(exc)}))
            error = f"robot link lost: {exc}"
        finally:
            conn.close()
        return finish(plan, h, statuses, error, self.history, ep)

    def _session(self, conn: LineConn, run: "_Run", todo: list[int]) -> str | None:
        """Handshake, then the steps in order; the first error, stop or lie ends it (returns why)."""
        self._send(conn, {"type": "hello", "protocol": PROTOCOL, "client": "shelfpick",
                          "plan": run.hash, "steps": len(run.plan.sequence), "run": run.run_id})
        hello = self._wait(conn, {"hello", "error"}, time.monotonic() + self.timeouts.ack, run.stop, "hello")
        if hello == "stop":
            i, box = todo[0], run.plan.sequence[todo[0]]
            emit(run.on_event, RobotEvent("aborted", i, box, {"reason": "stop requested"}))
            run.statuses[i] = {"step": i, "box": box, "status": "aborted", "detail": {"reason": "stop requested"}}
            return f"stopped by request before step {i + 1} ({box})"
        assert isinstance(hello, dict)
        if hello["type"] == "error":
            raise _Lost("REFUSED", f"robot refused the session: {clip(hello.get('code', 'REFUSED'))} "
                        f"{clip(hello.get('message', ''))}".rstrip())
        if hello.get("protocol") != PROTOCOL:
            raise _Lost("PROTOCOL", f"robot speaks {clip(hello.get('protocol'))!r}, expected {PROTOCOL!r}")
        self.robot_info = dict(hello)
        for n, i in enumerate(todo):
            error = self._step(conn, run, i)
            if run.statuses.get(i, {}).get("status") == "done":
                held = self._verify(conn, run, i)
                if held is not None and error is None and n < len(todo) - 1:
                    error = f"held after step {i + 1} ({run.plan.sequence[i]}): {held}"
                    self._bye(conn, run, "held")
                elif held is not None and error is not None:
                    error = f"{error}; held: {held}"
            if error is not None:
                return error
        self._bye(conn, run, None)
        return None

    def _bye(self, conn: LineConn, run: "_Run", reason: str | None) -> None:
        msg: dict[str, Any] = {"type": "bye", "plan": run.hash, "run": run.run_id}
        if reason:
            msg["reason"] = reason
        try:
            conn.send(msg)
        except OSError:
            pass

    def _verify(self, conn: LineConn, run: "_Run", i: int) -> str | None:
        """The console's look after step `i`, the link kept alive meanwhile (pings answered and sent).

        Nothing is sent to the robot but pings until the look is judged; a robot
        that replies with a step message meanwhile broke the protocol.
        """
        if self.verify is None:
            return None
        box = run.plan.sequence[i]
        answer: list = []
        judged = threading.Event()

        def look() -> None:
            try:
                answer.append(self.verify(i, box, None))
            except Exception as exc:  # noqa: BLE001 - no verdict is no permission to go on
                answer.append(f"verification failed: {exc.__class__.__name__}: {exc}")
            finally:
                judged.set()

        threading.Thread(target=look, name="shelfpick-verify", daemon=True).start()
        self._wait(conn, set(), time.monotonic() + max(self.timeouts.step, 60.0), judged,
                   f"the verification of step {i + 1}")
        judged.wait()
        return answer[0] if answer else "verification gave no answer"

    def _step(self, conn: LineConn, run: "_Run", i: int) -> str | None:
        """Send step `i`, wait for its ack and its done; None when it is done and nothing fell."""
        box_id = run.plan.sequence[i]
        if run.stop.is_set():
            return self._abort(conn, run, None, i)
        msg = step_message(run.hash, i, run.scene.box(box_id), run.scene, self.transform, run.run_id)
        unrecorded = record_before_sending(self.record_sent, run.statuses, i, box_id)
        if unrecorded is not None:
            return unrecorded
        run.pending = i  # sent, not acknowledged: the robot must not move before its ack
        self._send(conn, msg)
        expect = (run.hash, i, box_id)
        reply = self._wait(conn, {"ack", "error"}, time.monotonic() + self.timeouts.ack, run.stop,
                           f"ack of step {i + 1}", expect)
        if reply == "stop":  # the step may or may not have been taken up: ask the robot to abort it
            return self._abort(conn, run, i, i)
        assert isinstance(reply, dict)
        if reply["type"] == "error":
            run.pending = None  # refused before acknowledging: nothing moved
            return self._step_error(reply, run, i)
        run.pending, run.current = None, i
        self.history.mark_unknown(self.name, run.hash, i, box_id)
        emit(run.on_event, RobotEvent("ack", i, box_id, {k: v for k, v in reply.items()
                                                         if k not in ("type", "plan", "step", "box")}))
        reply = self._wait(conn, {"done", "error"}, time.monotonic() + self.timeouts.step, run.stop,
                           f"completion of step {i + 1}", expect)
        if reply == "stop":
            return self._abort(conn, run, i, i)
        assert isinstance(reply, dict)
        if reply["type"] == "error":
            self.history.settle(self.name, run.hash, i)  # the robot says it failed: not done, not in flight
            run.current = None
            return self._step_error(reply, run, i)
        detail = self._done(run, i, reply)
        fallen = collapsed_ids(detail)
        if fallen:
            return f"step {i + 1} ({box_id}): the robot reports collapsed boxes: {', '.join(fallen)}"
        return None

    def _done(self, run: "_Run", i: int, reply: Mapping[str, Any]) -> dict:
        """Record step `i` as done (the history first: nothing after it can lose the finished box)."""
        box = run.plan.sequence[i]
        self.history.mark_done(self.name, run.hash, i, box)
        run.current = None
        detail = reply_detail(reply.get("detail"))
        run.statuses[i] = {"step": i, "box": box, "status": "done", "detail": detail}
        emit(run.on_event, RobotEvent("done", i, box, detail))
        return detail

    def _lost(self, run: "_Run", exc: _Lost) -> str:
        """The link failed, went silent or the peer broke the protocol: say which step is unknown."""
        plan, ep = run.plan, self.name
        if exc.code in DISTRUSTED and run.pending is not None:
            # a peer that lies or garbles may have moved without its ack: the step is unknown, never re-sent
            self.history.mark_unknown(ep, run.hash, run.pending, plan.sequence[run.pending])
            run.current, run.pending = run.pending, None
        info = {"code": exc.code, "message": str(exc)}
        if run.pending is not None and run.pending not in run.statuses:
            run.statuses[run.pending] = {"step": run.pending, "box": plan.sequence[run.pending],
                                         "status": "unacknowledged", "detail": info}
        current = run.current
        if current is not None and current not in run.statuses:
            run.statuses[current] = {"step": current, "box": plan.sequence[current], "status": "unknown",
                                     "detail": info}
        else:
            current = None
        emit(run.on_event, RobotEvent("disconnected", current,
                                      plan.sequence[current] if current is not None else None, info))
        what = "robot broke the protocol" if exc.code in DISTRUSTED else "robot link lost"
        return f"{what} ({exc.code}): {exc}" + (
            f"; step {current + 1} ({plan.sequence[current]}) was in flight, its outcome is unknown"
            if current is not None else "")

    def _step_error(self, reply: Mapping[str, Any], run: "_Run", i: int) -> str:
        box = run.plan.sequence[i]
        code = clip(reply.get("code", "ERROR"), 60)
        message = clip(reply.get("message", ""))
        detail = {**reply_detail(reply.get("detail")), "code": code, "message": message}
        emit(run.on_event, RobotEvent("error", i, box, detail))
        run.statuses[i] = {"step": i, "box": box, "status": "error", "detail": detail}
        return f"robot error at step {i + 1} ({box}): {code}" + (f": {message}" if message else "")

    def _abort(self, conn: LineConn, run: "_Run", step: int | None, i: int, reason: str = "stop requested") -> str:
        """Tell the robot to stop; wait briefly for `aborted` (or a `done` that beat the abort).

        `step`: the step sent (None: nothing sent yet). A sent step whose abort
        is not confirmed may have moved: it is unknown, and the plan is blocked.
        """
        box = run.plan.sequence[i]
        want = {"aborted", "done", "error"} if step is not None else {"aborted", "error"}
        try:
            self._send(conn, {"type": "abort", "plan": run.hash, "step": step, "reason": reason,
                              "run": run.run_id})
            reply = self._wait(conn, want, time.monotonic() + self.timeouts.abort, None, "abort confirmation",
                               (run.hash, step, box if step is not None else None))
        except _Lost as exc:
            reply, unconfirmed = None, f"{exc.code}: {exc}"
        if isinstance(reply, dict) and step is not None and (
                reply["type"] == "done" or (reply["type"] == "aborted" and reply.get("completed") is True)):
            self._done(run, step, reply)
            return f"stopped by request after step {step + 1} ({box})"
        if reply is None and step is not None:
            self.history.mark_unknown(self.name, run.hash, step, box)
            run.current = None
            info = {"reason": reason, "unconfirmed": unconfirmed}
            emit(run.on_event, RobotEvent("aborted", i, box, info))
            run.statuses[i] = {"step": i, "box": box, "status": "unknown", "detail": info}
            return (f"stopped by request at step {i + 1} ({box}); the robot did not confirm the abort "
                    f"({unconfirmed}), so that step's outcome is unknown")
        if step is not None:
            self.history.settle(self.name, run.hash, step)
            run.current = run.pending = None
        detail = reply_detail(reply.get("detail")) if isinstance(reply, dict) else {}
        emit(run.on_event, RobotEvent("aborted", i, box, {**detail, "reason": reason}))
        run.statuses[i] = {"step": i, "box": box, "status": "aborted", "detail": {"reason": reason}}
        return f"stopped by request at step {i + 1} ({box})"


# --------------------------------------------------------------------------
@dataclass
class _Run:
    """One plan run over one connection: what was sent, what is acknowledged, per-step statuses."""

    plan: Plan
    hash: str
    scene: Scene
    on_event: Callable[[RobotEvent], None]
    stop: threading.Event
    statuses: dict[int, dict]
    run_id: str                  # sent in hello and every step: the robot keys "already done" by it
    pending: int | None = None   # sent, not yet acknowledged
    current: int | None = None   # acknowledged, not yet done: unknown if the link drops


def clip(value: Any, n: int = MAX_TEXT) -> str:
    """A peer's text, as text, at most `n` characters (it is shown and stored, never interpreted)."""
    s = value if isinstance(value, str) else json.dumps(value, default=str)
    return s if len(s) <= n else s[:n] + "..."


def reply_detail(value: Any) -> dict:
    """A reply's `detail` as a dict: an object is kept; a string, number or list goes under `text`."""
    if value is None:
        return {}
    if isinstance(value, Mapping):
        return {str(k): v for k, v in value.items()}
    return {"text": clip(value)}


def collapsed_ids(detail: Mapping[str, Any]) -> list[str]:
    """Boxes a `done` detail says collapsed: a list, or one id given on its own."""
    c = detail.get("collapsed")
    if not c:
        return []
    return [clip(x, 80) for x in c] if isinstance(c, list) else [clip(c, 80)]


def check_reply(msg: Mapping[str, Any], plan_hash: str, step: int | None, box: str | None) -> None:
    """A step reply must name the plan, the step (an integer; none for an abort before any step)
    and, when it names a box, the step's box; anything else is _Lost("PROTOCOL")."""
    kind = msg["type"]
    if msg.get("plan") != plan_hash:
        raise _Lost("PROTOCOL", f"{kind!r} names plan {clip(msg.get('plan'), 80)}, not {plan_hash}")
    s = msg.get("step")
    if step is None:
        if s is not None:
            raise _Lost("PROTOCOL", f"{kind!r} names step {clip(s, 80)}, but no step was sent")
    elif type(s) is not int or s != step:
        what = "no step" if s is None else f"step {clip(s, 80)}"
        raise _Lost("PROTOCOL", f"{kind!r} names {what}, expected step {step}")
    if box is not None and "box" in msg and msg["box"] != box:
        raise _Lost("PROTOCOL", f"{kind!r} for step {step} names box {clip(msg['box'], 80)}, expected {box!r}")


__all__ = ["TcpRobot", "Transform", "Timeouts", "LineConn", "ProtocolError", "FloodError", "PROTOCOL",
           "ERROR_CODES", "grasp_for", "step_message", "new_run_id", "check_reply", "reply_detail", "clip"]
