"""The TCP robot driver and the wire protocol `shelfpick.robot/1` (docs/robot-protocol.md).

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
"""
from __future__ import annotations

import json
import math
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence
from urllib.parse import parse_qs, urlsplit

from perception.errors import FormatError
from perception.scene import Box, Scene, quat_to_matrix, read_json
from planning.plan import Plan

from console.robot import (HISTORY, RobotError, RobotEvent, RobotOutcome, StepHistory, emit, finish)

PROTOCOL = "shelfpick.robot/1"
MAX_LINE = 1 << 20
PULL_CLEARANCE = 0.05   # m beyond the shelf's front edge the box's back face is pulled
ERROR_CODES = ("BAD_REQUEST", "REFUSED", "BUSY", "DUPLICATE_STEP", "NO_BOX_AT_GRASP", "PICK_FAILED",
               "ABORTED", "INTERNAL")

Vec3 = tuple[float, float, float]


# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Transform:
    """Rigid shelf-to-robot-base transform: p_robot = R @ p_shelf + t (metres)."""

    rotation: tuple[tuple[float, float, float], ...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
    translation: Vec3 = (0.0, 0.0, 0.0)

    @classmethod
    def identity(cls) -> "Transform":
        return cls()

    @classmethod
    def from_pose(cls, position: Sequence[float], wxyz: Sequence[float]) -> "Transform":
        n = math.sqrt(sum(float(c) * float(c) for c in wxyz))
        if not 0.999 <= n <= 1.001:
            raise FormatError("", "orientation", f"quaternion (w, x, y, z) is not unit length (|q|={n:.4f})")
        r = quat_to_matrix([float(c) / n for c in wxyz])
        return cls(tuple(tuple(float(v) for v in row) for row in r), tuple(float(v) for v in position))

    @classmethod
    def from_json(cls, doc: Any, origin: str = "") -> "Transform":
        """`{"matrix": 4x4}` or `{"position": [x,y,z], "orientation": [w,x,y,z]}` (shelf pose in robot base)."""
        if not isinstance(doc, Mapping):
            raise FormatError(origin, "transform", f"expected an object, got {type(doc).__name__}")
        if "matrix" in doc:
            m = doc["matrix"]
            if (not isinstance(m, list) or len(m) != 4
                    or not all(isinstance(r, list) and len(r) == 4 for r in m)
                    or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                               for r in m for v in r)):
                raise FormatError(origin, "matrix", f"expected 4 rows of 4 numbers, got {m!r}")
            if [float(v) for v in m[3]] != [0.0, 0.0, 0.0, 1.0]:
                raise FormatError(origin, "matrix[3]", f"last row must be [0, 0, 0, 1], got {m[3]!r}")
            rot = tuple(tuple(float(v) for v in m[i][:3]) for i in range(3))
            t = cls(rot, tuple(float(m[i][3]) for i in range(3)))
        elif "position" in doc or "orientation" in doc:
            pos = doc.get("position", [0.0, 0.0, 0.0])
            quat = doc.get("orientation", [1.0, 0.0, 0.0, 0.0])
            for name, v, n in (("position", pos, 3), ("orientation", quat, 4)):
                if (not isinstance(v, list) or len(v) != n
                        or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x)
                                   for x in v)):
                    raise FormatError(origin, name, f"expected a list of {n} numbers, got {v!r}")
            norm = math.sqrt(sum(c * c for c in quat))
            if abs(norm - 1.0) > 1e-3:
                raise FormatError(origin, "orientation", f"quaternion (w, x, y, z) is not unit length "
                                  f"(|q|={norm:.4f}): {quat!r}")
            t = cls.from_pose(pos, [c / norm for c in quat])
        else:
            raise FormatError(origin, "transform", "expected 'matrix' or 'position'/'orientation'")
        t.check(origin)
        return t

    @classmethod
    def load(cls, path: str | Path) -> "Transform":
        return cls.from_json(read_json(path), str(path))

    def check(self, origin: str = "") -> None:
        r = self.rotation
        for i in range(3):
            for j in range(3):
                dot = sum(r[k][i] * r[k][j] for k in range(3))
                if abs(dot - (1.0 if i == j else 0.0)) > 1e-4:
                    raise FormatError(origin, "matrix", "rotation part is not orthonormal")
        det = (r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0])
               + r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]))
        if det < 0:
            raise FormatError(origin, "matrix", "rotation part is a reflection (determinant -1)")

    def direction(self, v: Sequence[float]) -> Vec3:
        r = self.rotation
        return tuple(r[i][0] * v[0] + r[i][1] * v[1] + r[i][2] * v[2] for i in range(3))  # type: ignore

    def point(self, p: Sequence[float]) -> Vec3:
        d = self.direction(p)
        return tuple(d[i] + self.translation[i] for i in range(3))  # type: ignore[return-value]

    def inverse(self) -> "Transform":
        rt = tuple(tuple(self.rotation[j][i] for j in range(3)) for i in range(3))
        inv = Transform(rt, (0.0, 0.0, 0.0))
        t = inv.direction(self.translation)
        return Transform(rt, (-t[0], -t[1], -t[2]))

    def matrix(self) -> list[list[float]]:
        return [list(self.rotation[i]) + [self.translation[i]] for i in range(3)] + [[0.0, 0.0, 0.0, 1.0]]

    def to_json(self) -> dict:
        return {"matrix": self.matrix()}


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


def step_message(plan_hash: str, step: int, box: Box, scene: Scene, transform: Transform) -> dict:
    return {"type": "step", "plan": plan_hash, "step": step, "box": box.id, "frame": "robot_base",
            **grasp_for(box, scene, transform)}


# --------------------------------------------------------------------------
class ProtocolError(Exception):
    """The peer sent something that is not a protocol message."""


class LineConn:
    """Line-delimited JSON on a socket: send(dict), recv(timeout) -> dict | None (None = nothing yet)."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self._buf = b""
        self._send_lock = threading.Lock()

    def send(self, msg: Mapping[str, Any]) -> None:
        data = (json.dumps(msg, separators=(",", ":")) + "\n").encode()
        with self._send_lock:
            self.sock.sendall(data)

    def recv(self, timeout: float) -> dict | None:
        """Next message, None if none within `timeout`; ConnectionError on EOF."""
        deadline = time.monotonic() + max(timeout, 0.0)
        while b"\n" not in self._buf:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                return None
            except OSError as exc:
                raise ConnectionError(f"connection lost ({exc})") from None
            if not chunk:
                raise ConnectionError("connection closed by the peer")
            self._buf += chunk
            if len(self._buf) > MAX_LINE and b"\n" not in self._buf:
                raise ProtocolError(f"line longer than {MAX_LINE} bytes")
        line, self._buf = self._buf.split(b"\n", 1)
        if not line.strip():
            return self.recv(max(deadline - time.monotonic(), 0.0))
        try:
            msg = json.loads(line)
        except (json.JSONDecodeError, UnicodeDecodeError) as exc:
            raise ProtocolError(f"not JSON: {line[:80]!r} ({exc})") from None
        if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
            raise ProtocolError(f"expected an object with a string 'type', got {line[:80]!r}")
        return msg

    def close(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()


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
        self.timeouts = timeouts or Timeouts()
        self.history = history or HISTORY
        self.robot_info: dict = {}

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
        from console.robot import _query_float

        t = Timeouts(connect=_query_float(q, "connect_timeout", spec, t.connect),
                     ack=_query_float(q, "ack_timeout", spec, t.ack),
                     step=_query_float(q, "step_timeout", spec, t.step),
                     heartbeat_interval=_query_float(q, "heartbeat", spec, t.heartbeat_interval),
                     heartbeat_timeout=_query_float(q, "heartbeat_timeout", spec, t.heartbeat_timeout),
                     abort=_query_float(q, "abort_timeout", spec, t.abort))
        return cls(parts.hostname, port, transform, t)

    # ------------------------------------------------------------------ waiting
    def _wait(self, conn: LineConn, want: set[str], step: int | None, deadline: float,
              stop: threading.Event | None, what: str) -> dict | str:
        """Next message of a wanted type for `step`, answering pings and sending ours.

        Returns the message, or "stop" when `stop` is set. Raises _Lost on a
        disconnect, heartbeat silence or the deadline.
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
                try:
                    conn.send({"type": "ping", "seq": seq})
                except OSError as exc:
                    raise _Lost("DISCONNECTED", f"connection lost ({exc})") from None
                next_ping = now + t.heartbeat_interval
            try:
                msg = conn.recv(min(0.05, max(deadline - now, 0.0)))
            except ConnectionError as exc:
                raise _Lost("DISCONNECTED", str(exc)) from None
            except ProtocolError as exc:
                raise _Lost("PROTOCOL", f"robot sent garbage: {exc}") from None
            if msg is None:
                continue
            last_heard = time.monotonic()
            kind = msg["type"]
            if kind == "ping":
                try:
                    conn.send({"type": "pong", "seq": msg.get("seq")})
                except OSError as exc:
                    raise _Lost("DISCONNECTED", f"connection lost ({exc})") from None
                continue
            if kind in want and (step is None or msg.get("step") in (step, None) or kind == "hello"):
                return msg

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
        t = self.timeouts
        try:
            sock = socket.create_connection((self.host, self.port), timeout=t.connect)
        except OSError as exc:
            msg = f"cannot connect to the robot at {self.name} ({exc})"
            emit(on_event, RobotEvent("disconnected", None, None, {"code": "CONNECT", "message": msg}))
            return finish(plan, h, statuses, msg, self.history, ep)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        conn = LineConn(sock)
        error: str | None = None
        current: int | None = None   # acknowledged, not yet done: its outcome is unknown if the link drops
        pending: int | None = None   # sent, not yet acknowledged
        try:
            conn.send({"type": "hello", "protocol": PROTOCOL, "client": "shelfpick",
                       "plan": h, "steps": len(plan.sequence)})
            hello = self._wait(conn, {"hello", "error"}, None, time.monotonic() + t.ack, None, "hello")
            if isinstance(hello, dict) and hello["type"] == "error":
                raise _Lost(str(hello.get("code", "REFUSED")), f"robot refused the session: "
                            f"{hello.get('message', '')}")
            if isinstance(hello, dict) and hello.get("protocol") != PROTOCOL:
                raise _Lost("PROTOCOL", f"robot speaks {hello.get('protocol')!r}, expected {PROTOCOL!r}")
            self.robot_info = dict(hello) if isinstance(hello, dict) else {}
            for i in todo:
                box_id = plan.sequence[i]
                if stop.is_set():
                    error = self._abort(conn, h, None, "stop requested", on_event, i, box_id, statuses)
                    break
                msg = step_message(h, i, scene.box(box_id), scene, self.transform)
                pending = i  # sent, not acknowledged: the robot must not move before its ack
                conn.send(msg)
                reply = self._wait(conn, {"ack", "error"}, i, time.monotonic() + t.ack, stop, f"ack of step {i + 1}")
                if reply == "stop":
                    # the step may or may not have been taken up: ask the robot to abort it
                    error = self._abort(conn, h, i, "stop requested", on_event, i, box_id, statuses)
                    break
                if reply["type"] == "error":
                    error = self._step_error(reply, i, box_id, on_event, statuses)
                    pending = None  # refused before acknowledging: nothing moved
                    break
                pending, current = None, i
                self.history.mark_unknown(ep, h, i, box_id)
                emit(on_event, RobotEvent("ack", i, box_id, {k: v for k, v in reply.items()
                                                              if k not in ("type", "plan", "step")}))
                reply = self._wait(conn, {"done", "error"}, i, time.monotonic() + t.step, stop,
                                   f"completion of step {i + 1}")
                if reply == "stop":
                    error = self._abort(conn, h, i, "stop requested", on_event, i, box_id, statuses)
                    break
                if reply["type"] == "error":
                    error = self._step_error(reply, i, box_id, on_event, statuses)
                    self._settle_unknown(ep, h, i)  # the robot says it failed: not done, not in flight
                    current = None
                    break
                detail = dict(reply.get("detail") or {})
                self.history.mark_done(ep, h, i, box_id)
                current = None
                emit(on_event, RobotEvent("done", i, box_id, detail))
                statuses[i] = {"step": i, "box": box_id, "status": "done", "detail": detail}
                if detail.get("collapsed"):
                    error = f"step {i + 1} ({box_id}): the robot reports collapsed boxes: " \
                            f"{', '.join(map(str, detail['collapsed']))}"
                    break
            else:
                try:
                    conn.send({"type": "bye", "plan": h})
                except OSError:
                    pass
        except _Lost as exc:
            if pending is not None and pending not in statuses:
                statuses[pending] = {"step": pending, "box": plan.sequence[pending], "status": "unacknowledged",
                                     "detail": {"code": exc.code, "message": str(exc)}}
            if current is not None and current not in statuses:
                statuses[current] = {"step": current, "box": plan.sequence[current], "status": "unknown",
                                     "detail": {"code": exc.code, "message": str(exc)}}
            else:
                current = None
            emit(on_event, RobotEvent("disconnected", current, plan.sequence[current] if current is not None
                                      else None, {"code": exc.code, "message": str(exc)}))
            error = f"robot link lost ({exc.code}): {exc}" + (
                f"; step {current + 1} ({plan.sequence[current]}) was in flight, its outcome is unknown"
                if current is not None else "")
        except OSError as exc:
            emit(on_event, RobotEvent("disconnected", current, None, {"code": "DISCONNECTED", "message": str(exc)}))
            error = f"robot link lost: {exc}"
        finally:
            conn.close()
        return finish(plan, h, statuses, error, self.history, ep)

    def _settle_unknown(self, ep: str, h: str, i: int) -> None:
        self.history.settle(ep, h, i)

    def _step_error(self, reply: dict, i: int, box: str, on_event: Callable[[RobotEvent], None],
                    statuses: dict[int, dict]) -> str:
        code = str(reply.get("code", "ERROR"))
        message = str(reply.get("message", ""))
        detail = {"code": code, "message": message, **(reply.get("detail") or {})}
        emit(on_event, RobotEvent("error", i, box, detail))
        statuses[i] = {"step": i, "box": box, "status": "error", "detail": detail}
        return f"robot error at step {i + 1} ({box}): {code}" + (f": {message}" if message else "")

    def _abort(self, conn: LineConn, h: str, step: int | None, reason: str,
               on_event: Callable[[RobotEvent], None], i: int, box: str, statuses: dict[int, dict]) -> str:
        """Tell the robot to stop; wait briefly for `aborted` (or a `done` that beat the abort)."""
        try:
            conn.send({"type": "abort", "plan": h, "step": step, "reason": reason})
            reply = self._wait(conn, {"aborted", "done", "error"}, step,
                               time.monotonic() + self.timeouts.abort, None, "abort confirmation")
        except (_Lost, OSError) as exc:
            reply = {"type": "aborted", "detail": {"unconfirmed": str(exc)}}
        if isinstance(reply, dict) and step is not None and (
                reply["type"] == "done" or (reply["type"] == "aborted" and reply.get("completed") is True)):
            detail = dict(reply.get("detail") or {})
            self.history.mark_done(self.name, h, step, box)
            emit(on_event, RobotEvent("done", step, box, detail))
            statuses[step] = {"step": step, "box": box, "status": "done", "detail": detail}
            return f"stopped by request after step {step + 1} ({box})"
        if step is not None:
            self._settle_unknown(self.name, h, step)
        emit(on_event, RobotEvent("aborted", i, box, {"reason": reason,
                                                      **(reply.get("detail") or {} if isinstance(reply, dict) else {})}))
        statuses[i] = {"step": i, "box": box, "status": "aborted", "detail": {"reason": reason}}
        return f"stopped by request at step {i + 1} ({box})"


__all__ = ["TcpRobot", "Transform", "Timeouts", "LineConn", "ProtocolError", "PROTOCOL", "ERROR_CODES",
           "grasp_for", "step_message"]
