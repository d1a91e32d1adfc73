"""Hostile robot peers on real sockets: the TCP driver stops, says which steps are done or unknown,
never sends a further step, and does so within a bounded time.

Each peer is a thread with a real listening socket on 127.0.0.1 that follows a
script: it disconnects mid-step, stalls, lies (wrong plan, wrong or missing
step, a `done` for a step never sent, a duplicate `done`), floods (blank
lines, huge lines, pings) or puts markup in its `error` text. Every case
counts into a tally printed at the end of the run (safety_kit.ROBOT_TALLY): faults injected, steps
that reached the peer after its fault (unapproved) or that the outcome does not
account for (unrecorded), and stops that did not stop; all but the first must
be 0.
"""
from __future__ import annotations

import json
import socket
import threading
import time
from typing import Callable

import pytest

from safety_kit import ROBOT_TALLY as TALLY
from shelfpick.console.robot.drivers import RobotEvent
from shelfpick.console.robot.tcp import LineConn, ProtocolError, Timeouts, TcpRobot
from shelfpick.console.robot.base import StepHistory
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.plan import Plan

FAST = Timeouts(connect=2.0, ack=1.0, step=2.0, heartbeat_interval=0.1, heartbeat_timeout=0.6, abort=0.5)
BOUND = 4.0  # s: the slowest fault (a stalled step) ends at step timeout + abort; nothing may take longer


def row_scene() -> Scene:
    return Scene(Shelf(1.0, 0.3, 1.6), tuple(
        Box(f"b{i}", (0.2, 0.2, 0.2), (-0.36 + 0.24 * i, 0.12, 0.1)) for i in range(4)))


PLAN = Plan("clear", None, "physics", ("b0", "b1", "b2", "b3"))
H = PLAN.content_hash()


# --------------------------------------------------------------------------
class Link:
    """The peer's side of one connection: reads lines itself (not with the code under test)."""

    def __init__(self, sock: socket.socket, peer: "Peer") -> None:
        self.sock, self.peer, self.buf = sock, peer, b""
        self.answer_pings = True

    def _line(self, timeout: float) -> bytes | None:
        end = time.monotonic() + timeout
        while b"\n" not in self.buf:
            left = end - time.monotonic()
            if left <= 0:
                return None
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                return None
            if not chunk:
                raise ConnectionError("console closed")
            self.buf += chunk
        line, self.buf = self.buf.split(b"\n", 1)
        return line

    def read(self, kind: str, timeout: float = 3.0) -> dict:
        """The next message of this type (pings answered on the way)."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            line = self._line(end - time.monotonic())
            if line is None:
                break
            msg = json.loads(line)
            self.peer.note(msg)
            if msg["type"] == "ping" and self.answer_pings:
                self.send({"type": "pong", "seq": msg.get("seq")})
            if msg["type"] == kind:
                return msg
        raise AssertionError(f"peer: no {kind!r} from the console")

    def fault(self) -> None:
        self.peer.fault()

    def send(self, msg: dict) -> None:
        self.raw((json.dumps(msg) + "\n").encode())

    def raw(self, data: bytes) -> None:
        self.sock.sendall(data)

    def handshake(self) -> dict:
        hello = self.read("hello")
        self.send({"type": "hello", "protocol": "shelfpick.robot/1", "robot": "hostile"})
        return hello

    def ack(self, m: dict, **over) -> None:
        self.send({"type": "ack", "plan": m["plan"], "step": m["step"], "box": m["box"], **over})

    def done(self, m: dict, **over) -> None:
        self.send({"type": "done", "plan": m["plan"], "step": m["step"], "box": m["box"], "detail": {}, **over})

    def honest_step(self) -> dict:
        m = self.read("step")
        self.ack(m)
        self.done(m)
        return m

    def hold(self, timeout: float = 8.0) -> None:
        """Keep reading (pings answered) until the console closes the connection."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            line = self._line(end - time.monotonic())
            if line is None:
                continue
            msg = json.loads(line)
            self.peer.note(msg)
            if msg["type"] == "ping" and self.answer_pings:
                self.send({"type": "pong", "seq": msg.get("seq")})


class Peer:
    """A robot peer on a real socket that follows `script(link)` on the console's connection."""

    def __init__(self, script: Callable[[Link], None]) -> None:
        self.script = script
        self.srv = socket.create_server(("127.0.0.1", 0))
        self.port = self.srv.getsockname()[1]
        self.lock = threading.Lock()
        self.messages: list[dict] = []
        self.fault_at: int | None = None  # index in messages when the fault was injected
        self.stop = threading.Event()      # the console's Stop button for this run
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._serve, daemon=True)
        self.thread.start()

    def note(self, msg: dict) -> None:
        with self.lock:
            self.messages.append(msg)

    def fault(self) -> None:
        with self.lock:
            self.fault_at = len(self.messages)

    def _serve(self) -> None:
        self.srv.settimeout(5)
        try:
            sock, _ = self.srv.accept()
        except OSError:
            return
        link = Link(sock, self)
        try:
            self.script(link)
            link.hold()
        except (OSError, ConnectionError):
            pass
        except Exception as exc:  # noqa: BLE001 - kept for the test to look at, not a thread crash
            self.error = exc
        finally:
            sock.close()
            self.srv.close()

    def steps(self, after_fault: bool = False) -> list[dict]:
        self.thread.join(10)
        with self.lock:
            msgs = self.messages[self.fault_at or 0:] if after_fault else self.messages
            return [m for m in msgs if m["type"] == "step"]


def drive(script: Callable[[Link], None], stop_when: Callable[[RobotEvent], bool] | None = None,
          plan: Plan = PLAN, history: StepHistory | None = None):
    """Run PLAN against a hostile peer; returns (outcome, events, peer, seconds).

    `stop_when(event)`: press Stop on that event (the peer's fault point); a
    script may also press it itself (`link.peer.stop`). `history`: the step
    history the driver is handed (as the console hands one per run); None: its own.
    """
    peer = Peer(script)
    events: list[RobotEvent] = []

    def on_event(ev: RobotEvent) -> None:
        events.append(ev)
        if stop_when is not None and not peer.stop.is_set() and stop_when(ev):
            peer.fault()  # from here on no step may reach the peer
            peer.stop.set()

    t0 = time.monotonic()
    out = TcpRobot("127.0.0.1", peer.port, timeouts=FAST, history=history).execute(plan, row_scene(), on_event,
                                                                                   peer.stop)
    elapsed = time.monotonic() - t0
    peer.steps()  # the peer has finished
    return out, events, peer, elapsed


def judged(out, events, peer, elapsed, *, stopped: bool = False) -> dict[int, str]:
    """The invariants every fault must keep; returns step -> status."""
    TALLY["faults"] += 1
    statuses = {s["step"]: s["status"] for s in out.steps}
    assert not out.ok and out.needs_replan and out.error
    assert elapsed < BOUND, f"took {elapsed:.1f} s"
    late = [m for m in peer.steps(after_fault=True) if peer.fault_at is not None]
    if stopped:
        TALLY["stops"] += 1
        TALLY["stops_not_stopping"] += int(bool(late) or elapsed >= BOUND)
    else:
        TALLY["unapproved"] += len(late)
    assert not late, f"console sent {[m['step'] for m in late]} after the fault"
    sent = {m["step"] for m in peer.steps()}
    unrecorded = [i for i in sent if statuses.get(i) in (None, "not_sent")]
    TALLY["unrecorded"] += len(unrecorded)
    assert not unrecorded, statuses
    assert all(statuses[i] in ("not_sent", "aborted") for i in range(4) if i not in sent)
    # what the console calls done is exactly what an honest `done` confirmed
    assert out.completed == tuple(PLAN.sequence[i] for i in sorted(statuses) if statuses[i] == "done")
    return statuses


# --------------------------------------------------------------------------
# disconnects
def drop_before_ack(link: Link) -> None:
    link.handshake()
    link.honest_step()
    link.read("step")
    link.fault()
    link.sock.shutdown(socket.SHUT_RDWR)


def drop_after_ack(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    link.fault()
    link.sock.shutdown(socket.SHUT_RDWR)


def drop_after_hello(link: Link) -> None:
    link.read("hello")
    link.fault()
    link.sock.shutdown(socket.SHUT_RDWR)


@pytest.mark.parametrize("script, statuses, code", [
    (drop_before_ack, {0: "done", 1: "unacknowledged"}, "DISCONNECTED"),
    (drop_after_ack, {0: "unknown"}, "DISCONNECTED"),
    (drop_after_hello, {}, "DISCONNECTED"),
], ids=["before-ack", "after-ack", "after-hello"])
def test_a_peer_that_disconnects(script, statuses, code) -> None:
    out, events, peer, elapsed = drive(script)
    st = judged(out, events, peer, elapsed)
    assert {i: s for i, s in st.items() if s != "not_sent"} == statuses
    assert events[-1].kind == "disconnected" and events[-1].detail["code"] == code
    assert ("unknown" in out.error) == ("unknown" in statuses.values())


# --------------------------------------------------------------------------
# stalls
def no_ack(link: Link) -> None:
    link.handshake()
    link.read("step")
    link.fault()  # never acknowledges, keeps answering pings


def no_done(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    link.fault()  # acknowledged, never finishes, keeps answering pings


def silent(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    link.fault()
    link.answer_pings = False  # gone quiet: no pong


def no_hello(link: Link) -> None:
    link.read("hello")
    link.fault()


@pytest.mark.parametrize("script, statuses, code", [
    (no_ack, {0: "unacknowledged"}, "TIMEOUT"),
    (no_done, {0: "unknown"}, "TIMEOUT"),
    (silent, {0: "unknown"}, "HEARTBEAT"),
    (no_hello, {}, "TIMEOUT"),
], ids=["no-ack", "no-done", "silent", "no-hello"])
def test_a_peer_that_stalls(script, statuses, code) -> None:
    out, events, peer, elapsed = drive(script)
    st = judged(out, events, peer, elapsed)
    assert {i: s for i, s in st.items() if s != "not_sent"} == statuses
    assert events[-1].kind == "disconnected" and events[-1].detail["code"] == code


# --------------------------------------------------------------------------
# lies: never counted as completion; the step in question is unknown; nothing further is sent
def lie(**over) -> Callable[[Link], None]:
    def script(link: Link) -> None:
        link.handshake()
        m = link.read("step")
        link.ack(m)
        link.fault()
        link.done(m, **over)
    return script


def ack_lie(**over) -> Callable[[Link], None]:
    def script(link: Link) -> None:
        link.handshake()
        m = link.read("step")
        link.fault()
        link.ack(m, **over)
    return script


def duplicate_done(link: Link) -> None:
    link.handshake()
    m0 = link.honest_step()
    m1 = link.read("step")
    link.ack(m1)
    link.fault()
    link.done(m0)  # step 0 again, while step 1 runs


def done_before_ack(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.fault()
    link.done(m)


def done_never_sent(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.fault()
    link.send({"type": "done", "plan": m["plan"], "step": 3, "box": "b3", "detail": {}})


def unsolicited_aborted(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    link.fault()
    link.send({"type": "aborted", "plan": m["plan"], "step": 0, "completed": True})


def second_ack(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    link.fault()
    link.ack(m)


def wrong_plan_error(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    link.fault()
    link.send({"type": "error", "plan": "0000000000000000", "step": 0, "code": "PICK_FAILED", "message": "x"})


LIES = {
    "done-wrong-plan-no-step": lie(plan="0123456789abcdef", step=None),
    "done-wrong-plan": lie(plan="0123456789abcdef"),
    "done-missing-step": lie(step=None),
    "done-wrong-step": lie(step=2),
    "done-step-true": lie(step=True),
    "done-step-string": lie(step="0"),
    "done-wrong-box": lie(box="b3"),
    "done-for-a-step-never-sent": done_never_sent,
    "duplicate-done": duplicate_done,
    "done-before-ack": done_before_ack,
    "ack-wrong-plan": ack_lie(plan="feedfeedfeedfeed"),
    "ack-wrong-step": ack_lie(step=1),
    "ack-missing-plan": ack_lie(plan=None),
    "second-ack": second_ack,
    "unsolicited-aborted": unsolicited_aborted,
    "error-wrong-plan": wrong_plan_error,
}


@pytest.mark.parametrize("name", list(LIES))
def test_a_peer_that_lies(name) -> None:
    history = StepHistory()
    out, events, peer, elapsed = drive(LIES[name], history=history)
    st = judged(out, events, peer, elapsed)
    lied_about = 1 if name == "duplicate-done" else 0
    assert st[lied_about] == "unknown", st
    assert "done" not in [st[i] for i in range(lied_about, 4)]
    assert events[-1].kind == "disconnected" and events[-1].detail["code"] == "PROTOCOL"
    assert "broke the protocol" in out.error and "unknown" in out.error
    # the plan is blocked: a second run with the same history sends nothing, since that step may have moved
    events2: list[RobotEvent] = []
    again = TcpRobot("127.0.0.1", peer.port, timeouts=FAST, history=history).execute(PLAN, row_scene(), events2.append,
                                                                    threading.Event())
    assert not again.ok and "not sent again" in again.error and events2 == []


# --------------------------------------------------------------------------
# floods
def flood(data: bytes, after_ack: bool = True) -> Callable[[Link], None]:
    def script(link: Link) -> None:
        link.handshake()
        m = link.read("step")
        if after_ack:
            link.ack(m)
        link.fault()
        try:
            link.raw(data)
        except OSError:
            pass  # the console hung up mid-flood: that is the point
    return script


PING = b'{"type":"ping","seq":1}\n'
FLOODS = {
    "5000-blank-lines": flood(b"\n" * 5000),
    "blank-lines-crlf": flood(b"\r\n" * 5000),
    "huge-line-no-newline": flood(b'{"type":"pong","x":"' + b"a" * (2 << 20)),
    "huge-line-with-newline": flood(b'{"type":"pong","x":"' + b"a" * ((1 << 20) + 10) + b'"}\n'),
    "10000-pings": flood(PING * 10000),
    "10000-unknown-types": flood(b'{"type":"chatter"}\n' * 10000),
    "nested-100k": flood(b"[" * 100_000 + b"\n"),
    "nested-object": flood(b'{"type":"done","detail":' + b'{"a":' * 50_000 + b"1" + b"}" * 50_001 + b"\n"),
    "5000-digit-number": flood(b'{"type":"pong","seq":' + b"9" * 5000 + b"}\n"),
    "nan": flood(b'{"type":"done","plan":"x","step":NaN}\n'),
    "not-json": flood(b"<html><script>alert(1)</script>\n"),
    "not-an-object": flood(b'["done", 0]\n'),
    "binary": flood(bytes(range(256)) * 10 + b"\n"),
    "blank-before-ack": flood(b"\n" * 5000, after_ack=False),
}


@pytest.mark.parametrize("name", list(FLOODS))
def test_a_peer_that_floods(name) -> None:
    out, events, peer, elapsed = drive(FLOODS[name])
    st = judged(out, events, peer, elapsed)
    assert st[0] == "unknown", st  # before or after its ack, a garbling peer may have moved
    assert events[-1].kind == "disconnected" and events[-1].detail["code"] == "PROTOCOL"


def test_5000_blank_lines_do_not_recurse_even_without_a_cap() -> None:
    """LineConn.recv skips blank lines in a loop: a cap set out of reach still returns the message."""
    a, b = socket.socketpair()
    try:
        conn = LineConn(a, max_blank=10 ** 9, max_rate=1e9, max_burst=10 ** 9)
        b.sendall(b"\n" * 50_000 + b'{"type":"pong","seq":3}\n')
        assert conn.recv(5.0) == {"type": "pong", "seq": 3}
        assert conn.blank_lines == 50_000
        capped = LineConn(b)
        a.sendall(b"\n" * 101)
        with pytest.raises(ProtocolError, match="more than 100 blank lines"):
            capped.recv(2.0)
    finally:
        a.close()
        b.close()


# --------------------------------------------------------------------------
# markup and odd payloads in the peer's own words: kept as data, clipped, the run stops
def error_with(message, detail=None, code="PICK_FAILED") -> Callable[[Link], None]:
    def script(link: Link) -> None:
        link.handshake()
        link.honest_step()
        m = link.read("step")
        link.ack(m)
        link.fault()
        msg = {"type": "error", "plan": m["plan"], "step": m["step"], "code": code, "message": message}
        if detail is not None:
            msg["detail"] = detail
        link.send(msg)
    return script


MARKUP = '<iframe src="javascript:alert(1)"></iframe><script>alert(2)</script>[x](http://evil.example/)'


@pytest.mark.parametrize("script", [
    error_with(MARKUP),
    error_with(MARKUP, detail="<b>bold</b>"),
    error_with("x" * 100_000, detail=["<img src=x onerror=alert(3)>"]),
    error_with({"nested": MARKUP}, code="<script>alert(4)</script>"),
], ids=["markup", "string-detail", "huge", "object-message"])
def test_a_peer_that_injects_markup_in_its_error(script) -> None:
    out, events, peer, elapsed = drive(script)
    st = judged(out, events, peer, elapsed)
    assert st[0] == "done" and st[1] == "error" and out.completed == ("b0",)
    err = events[-1]
    assert err.kind == "error" and err.step == 1
    # data, never interpreted: strings, at most 500 characters (+ "...")
    assert isinstance(err.detail["message"], str) and len(err.detail["message"]) <= 503
    assert isinstance(err.detail["code"], str) and len(err.detail["code"]) <= 63
    assert len(out.error) < 1200
    json.dumps(out.to_json())


# --------------------------------------------------------------------------
# a `done` whose detail is not an object: the box is done (item 7)
@pytest.mark.parametrize("detail", ["collapsed: none", 42, ["a", "b"], None])
def test_done_with_a_detail_that_is_no_object_keeps_the_finished_box(detail) -> None:
    def script(link: Link) -> None:
        link.handshake()
        for _ in range(4):
            m = link.read("step")
            link.ack(m)
            link.done(m, detail=detail)

    out, events, peer, elapsed = drive(script)
    assert out.ok and out.completed == PLAN.sequence, out
    dones = [e for e in events if e.kind == "done"]
    assert len(dones) == 4 and all(isinstance(e.detail, dict) for e in dones)
    assert dones[0].detail == ({} if detail is None else {"text": detail if isinstance(detail, str)
                                                          else json.dumps(detail)})


def test_a_done_naming_one_collapsed_box_as_a_string_stops_the_run() -> None:
    def script(link: Link) -> None:
        link.handshake()
        m = link.read("step")
        link.ack(m)
        link.fault()
        link.done(m, detail={"collapsed": "b1"})

    out, events, peer, elapsed = drive(script)
    st = judged(out, events, peer, elapsed)
    assert st[0] == "done" and "collapsed boxes: b1" in out.error


# --------------------------------------------------------------------------
# Stop while the peer misbehaves: abort sent, bounded, nothing further sent
def stall_no_ack_ignoring_abort(link: Link) -> None:
    link.handshake()
    link.honest_step()
    link.read("step")  # never acknowledged; the abort is never confirmed
    link.fault()
    link.peer.stop.set()


def flood_pings_during_step(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    for _ in range(200):
        link.raw(PING * 5)
        time.sleep(0.01)


def step_never_finishes_abort_confirmed(link: Link) -> None:
    link.handshake()
    m = link.read("step")
    link.ack(m)
    a = link.read("abort", timeout=5)
    link.send({"type": "aborted", "plan": a["plan"], "step": a["step"], "completed": False})


def on_ack(ev: RobotEvent) -> bool:
    return ev.kind == "ack"


@pytest.mark.parametrize("script, stop_when, status, abort_step", [
    (stall_no_ack_ignoring_abort, None, {0: "done", 1: "unknown"}, 1),
    (flood_pings_during_step, on_ack, {0: "unknown"}, None),  # too busy writing to read the abort
    (step_never_finishes_abort_confirmed, on_ack, {0: "aborted"}, 0),
], ids=["stall-unconfirmed", "ping-flood", "confirmed"])
def test_stop_reaches_a_misbehaving_peer(script, stop_when, status, abort_step) -> None:
    out, events, peer, elapsed = drive(script, stop_when=stop_when)
    st = judged(out, events, peer, elapsed, stopped=True)
    assert {i: s for i, s in st.items() if s != "not_sent"} == status
    assert "stop" in out.error
    if abort_step is not None:
        assert [m["step"] for m in peer.messages if m["type"] == "abort"] == [abort_step]
    assert peer.error is None, peer.error


def test_the_tally_has_no_unapproved_unrecorded_or_unstopped() -> None:
    """Runs last in this module (pytest keeps file order); meaningful only after the whole module."""
    if TALLY["faults"] < 40:
        pytest.skip("run the whole module for the tally")
    assert TALLY["faults"] >= 40
    assert TALLY["unapproved"] == TALLY["unrecorded"] == TALLY["stops_not_stopping"] == 0
