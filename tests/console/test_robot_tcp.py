"""The TCP robot driver against the reference robot-side controller, on real sockets."""
from __future__ import annotations

import json
import math
import socket
import threading
import time
from pathlib import Path

import pytest

from shelfpick.console.robot.drivers import RobotError, RobotEvent, open_robot
from shelfpick.robotsim.controller import RobotController
from shelfpick.console.robot.tcp import LineConn, Timeouts, TcpRobot, Transform, grasp_for
from shelfpick.console.robot.base import StepHistory
from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Box, Scene, Shelf, yaw_quat
from shelfpick.planning.plan import Plan

FAST = Timeouts(connect=2.0, ack=2.0, step=10.0, heartbeat_interval=0.1, heartbeat_timeout=0.6, abort=1.0)


def row_scene() -> Scene:
    """Four boxes side by side on the floor: any order is physically fine."""
    return Scene(Shelf(1.0, 0.3, 1.6), tuple(
        Box(f"b{i}", (0.2, 0.2, 0.2), (-0.36 + 0.24 * i, 0.12, 0.1)) for i in range(4)))


def clear_plan(seq=("b0", "b1", "b2", "b3")) -> Plan:
    return Plan("clear", None, "physics", tuple(seq))


def run(robot: TcpRobot, plan: Plan, scene: Scene, stop: threading.Event | None = None):
    events: list[RobotEvent] = []
    out = robot.execute(plan, scene, events.append, stop or threading.Event())
    return out, events


def driver(ctl: RobotController, **kw) -> TcpRobot:
    host, port = ctl.address
    return TcpRobot(host, port, timeouts=kw.pop("timeouts", FAST), **kw)


def test_full_plan_ok_and_messages_are_in_the_robot_frame() -> None:
    # the shelf frame sits 0.6 m in front of the robot base, turned 90 deg about z
    tf = Transform.from_pose((0.6, 0.0, -0.2), yaw_quat(math.pi / 2))
    with RobotController(transform=tf) as ctl:
        out, events = run(driver(ctl, transform=tf), clear_plan(), row_scene())
    assert out.ok and out.error is None and not out.needs_replan
    assert out.completed == ("b0", "b1", "b2", "b3")
    assert [e.kind for e in events] == ["ack", "done"] * 4
    assert [s["status"] for s in out.steps] == ["done"] * 4
    steps = ctl.received("step")
    assert [m["step"] for m in steps] == [0, 1, 2, 3] and [m["box"] for m in steps] == list(out.completed)
    m = steps[0]
    assert m["plan"] == clear_plan().content_hash() and m["frame"] == "robot_base"
    # b0 front face centre in the shelf frame is (-0.36, 0.02, 0.1): rotated +90 deg about z -> (-0.02, -0.36, 0.1)
    assert m["grasp"]["point"] == pytest.approx([0.6 - 0.02, -0.36, -0.2 + 0.1], abs=1e-6)
    assert m["grasp"]["approach"] == pytest.approx([-1.0, 0.0, 0.0], abs=1e-6)  # shelf +y in the robot frame
    assert m["grasp"]["normal"] == pytest.approx([1.0, 0.0, 0.0], abs=1e-6)
    assert m["pull_distance"] == pytest.approx(0.22 + 0.05)  # back face y=0.22 out past the front edge
    assert ctl.received("hello")[0]["protocol"] == "shelfpick.robot/1"


def test_disconnect_mid_plan_records_completed_and_never_resends() -> None:
    plan, scene, history = clear_plan(), row_scene(), StepHistory()   # the history the console would own
    with RobotController(drop_after=2) as ctl:
        out, events = run(driver(ctl, history=history), plan, scene)
        assert not out.ok and out.needs_replan
        assert out.completed == ("b0", "b1")
        assert "new capture and plan" in out.error and "lost" in out.error
        # step 2 may have gone out before the drop was noticed, but it was never acknowledged
        assert [s["status"] for s in out.steps][:2] == ["done", "done"]
        assert out.steps[2]["status"] in ("not_sent", "unacknowledged") and out.steps[3]["status"] == "not_sent"
        assert events[-1].kind == "disconnected"
        # retry the same plan on a fresh driver object with the same history: only steps 2 and 3 go out
        ctl.drop_after = None
        out2, events2 = run(driver(ctl, history=history), plan, scene)
    assert out2.ok and out2.completed == ("b0", "b1", "b2", "b3")
    assert [s["status"] for s in out2.steps] == ["skipped", "skipped", "done", "done"]
    sent = [m["step"] for m in ctl.received("step")]
    assert sent in ([0, 1, 2, 3], [0, 1, 2, 2, 3])  # completed steps never again; an unacknowledged one may be
    assert sent.count(0) == 1 and sent.count(1) == 1
    assert [e[1] for e in ctl.executed] == [0, 1, 2, 3]


def test_step_in_flight_when_link_drops_is_unknown_and_blocks_the_plan() -> None:
    plan, scene, history = clear_plan(), row_scene(), StepHistory()
    with RobotController(drop_during=1) as ctl:
        out, _ = run(driver(ctl, history=history), plan, scene)
        assert out.completed == ("b0",)
        assert [s["status"] for s in out.steps][:2] == ["done", "unknown"]
        assert "in flight" in out.error
        ctl.drop_during = None
        out2, events2 = run(driver(ctl, history=history), plan, scene)
    assert not out2.ok and "not sent again" in out2.error and events2 == []
    assert [m["step"] for m in ctl.received("step")] == [0, 1]  # step 1 was executed once, never re-sent


def test_refused_step_stops_the_sequence() -> None:
    with RobotController(refuse_steps={1}) as ctl:
        out, events = run(driver(ctl), clear_plan(), row_scene())
    assert not out.ok and out.completed == ("b0",)
    assert "REFUSED" in out.error and out.needs_replan
    assert [e.kind for e in events] == ["ack", "done", "error"]
    assert events[-1].detail["code"] == "REFUSED" and events[-1].step == 1
    assert [s["status"] for s in out.steps] == ["done", "error", "not_sent", "not_sent"]
    assert [m["step"] for m in ctl.received("step")] == [0, 1]


def test_heartbeat_timeout_when_the_robot_goes_silent() -> None:
    with RobotController(hang_on_step=2) as ctl:
        t0 = time.monotonic()
        out, events = run(driver(ctl), clear_plan(), row_scene())
        elapsed = time.monotonic() - t0
        pings = ctl.received("ping")
    assert not out.ok and out.completed == ("b0", "b1")
    assert events[-1].kind == "disconnected" and events[-1].detail["code"] in ("HEARTBEAT", "TIMEOUT")
    assert "silent" in out.error or "no ack" in out.error
    assert elapsed < 5.0
    assert pings, "the driver pings while it waits"


def test_heartbeat_keeps_a_slow_step_alive_and_step_timeout_fires() -> None:
    with RobotController(step_time=1.0) as ctl:
        out, _ = run(driver(ctl), clear_plan(("b0",)), row_scene())
        assert out.ok  # 1 s step with a 0.6 s silence limit: pongs keep the link alive
        assert len(ctl.received("ping")) >= 3
        slow = Timeouts(connect=2, ack=2, step=0.4, heartbeat_interval=0.1, heartbeat_timeout=0.6, abort=0.5)
        out2, events2 = run(driver(ctl, timeouts=slow), clear_plan(("b1",)), row_scene())
    assert not out2.ok and events2[-1].detail["code"] == "TIMEOUT"
    assert "completion of step 1" in out2.error


def test_stop_aborts_the_running_step() -> None:
    stop = threading.Event()
    with RobotController(step_time=0.6) as ctl:
        events: list[RobotEvent] = []

        def on_event(ev: RobotEvent) -> None:
            events.append(ev)
            if ev.kind == "ack" and ev.step == 1:
                stop.set()

        out = driver(ctl).execute(clear_plan(), row_scene(), on_event, stop)
        aborts = ctl.received("abort")
    assert out.completed == ("b0",) and not out.ok
    assert "stopped" in out.error
    assert aborts and aborts[0]["step"] == 1
    assert events[-1].kind == "aborted" and events[-1].step == 1
    assert [s["status"] for s in out.steps] == ["done", "aborted", "not_sent", "not_sent"]


def test_connect_refused_and_bad_specs(tmp_path: Path) -> None:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    out, events = run(TcpRobot("127.0.0.1", port, timeouts=FAST), clear_plan(), row_scene())
    assert not out.ok and "cannot connect" in out.error and events[0].kind == "disconnected"
    with pytest.raises(RobotError, match="expected 'sim' or 'tcp://HOST:PORT'"):
        open_robot("udp://x:1")
    with pytest.raises(RobotError, match="unknown option 'bogus'"):
        open_robot("tcp://127.0.0.1:9?bogus=1")
    with pytest.raises(RobotError, match="position: expected 3"):
        open_robot("tcp://127.0.0.1:9?position=1,2")
    bad = tmp_path / "t.json"
    bad.write_text(json.dumps({"matrix": [[2, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]}))
    with pytest.raises(FormatError, match="t.json: matrix: rotation part is not orthonormal"):
        open_robot(f"tcp://127.0.0.1:9?transform={bad}")
    good = tmp_path / "g.json"
    good.write_text(json.dumps({"position": [0.5, 0, 0], "orientation": [1, 0, 0, 0]}))
    r = open_robot(f"tcp://127.0.0.1:9?transform={good}&ack_timeout=0.5")
    assert isinstance(r, TcpRobot) and r.transform.translation == (0.5, 0.0, 0.0) and r.timeouts.ack == 0.5
    r2 = open_robot("tcp://localhost:9?position=1,2,3&orientation=0.7071068,0,0,0.7071068")
    assert r2.transform.point((1, 0, 0)) == pytest.approx((1, 3, 3), abs=1e-6)


def test_transform_inverse_and_grasp_of_a_turned_box() -> None:
    tf = Transform.from_pose((0.3, -0.1, 0.5), (0.9238795, 0.0, 0.0, 0.3826834))
    p = (0.1, 0.2, 0.3)
    assert tf.inverse().point(tf.point(p)) == pytest.approx(p, abs=1e-9)
    box = Box("t", (0.2, 0.2, 0.2), (0.0, 0.15, 0.1), yaw_quat(math.radians(30)))
    scene = Scene(Shelf(), (box,))
    g = grasp_for(box, scene, Transform.identity())
    assert g["grasp"]["point"] == pytest.approx(box.front_center, abs=1e-6)
    assert g["grasp"]["normal"] == pytest.approx((math.sin(math.radians(30)), -math.cos(math.radians(30)), 0), abs=1e-6)
    unseen = Box("u", (0.2, 0.05, 0.2), (0.0, 0.05, 0.1), depth_known=False)
    assert grasp_for(unseen, scene, Transform.identity())["pull_distance"] == pytest.approx(0.30 + 0.05)


def test_controller_answers_pings_and_rejects_bad_requests() -> None:
    with RobotController() as ctl:
        sock = socket.create_connection(ctl.address, timeout=2)
        conn = LineConn(sock)
        conn.send({"type": "ping", "seq": 7})
        assert conn.recv(2) == {"type": "pong", "seq": 7}
        conn.send({"type": "step", "plan": "p", "step": 0, "box": "b0", "grasp": {}, "pull_distance": 0.3})
        err = conn.recv(2)
        assert err["type"] == "error" and err["code"] == "BAD_REQUEST"
        sock.sendall(b"not json\n")
        assert conn.recv(2)["code"] == "BAD_REQUEST"
        conn.close()


def test_controller_executes_on_a_truth_scene_through_the_transform() -> None:
    """The robot finds boxes by grasp point (robot frame -> shelf frame), not by id; a collapse stops the plan."""
    truth = Scene(Shelf(1.0, 0.3, 1.6), (
        Box("b0", (0.2, 0.2, 0.2), (0.0, 0.12, 0.1)),
        Box("b1", (0.2, 0.2, 0.2), (0.0, 0.12, 0.3)),
        Box("b2", (0.2, 0.2, 0.2), (0.3, 0.12, 0.1))))
    perceived = Scene(truth.shelf, tuple(Box(n, b.size, b.position) for n, b in zip(("x", "y", "z"), truth.boxes)))
    tf = Transform.from_pose((0.8, 0.1, -0.3), yaw_quat(-math.pi / 2))
    with RobotController(truth=truth, transform=tf) as ctl:
        # PyBullet holds the GIL while it steps: give the in-process controller room to answer pings
        patient = Timeouts(connect=2, ack=5, step=60, heartbeat_interval=0.2, heartbeat_timeout=10, abort=2)
        out, events = run(driver(ctl, transform=tf, timeouts=patient),
                          Plan("extract", "x", "heuristic", ("z", "x", "y")), perceived)
        world = ctl.world()
    assert out.completed == ("z", "x") and not out.ok, (out, events)
    done = [e for e in events if e.kind == "done"]
    assert [e.detail["true_box"] for e in done] == ["b2", "b0"]
    assert done[1].detail["collapsed"] == ["b1"] and "collapsed boxes: b1" in out.error
    assert out.steps[2]["status"] == "not_sent"
    assert "b0" not in world.ids and "b2" not in world.ids


def test_controller_as_a_separate_process(tmp_path: Path) -> None:
    """`python -m shelfpick.robotsim` in its own process, driven through open_robot's spec."""
    import subprocess
    import sys

    root = Path(__file__).resolve().parents[2]
    tf = tmp_path / "cell.json"
    tf.write_text(json.dumps({"position": [0.6, 0.0, -0.2], "orientation": [1, 0, 0, 0]}))
    proc = subprocess.Popen([sys.executable, "-m", "shelfpick.robotsim", "--port", "0", "--step-time", "0.05",
                             "--transform", str(tf), "--refuse", "3"],
                            cwd=root, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        line = proc.stdout.readline()
        url = line.split("listening on ")[1].split()[0]
        robot = open_robot(f"{url}?transform={tf}&heartbeat=0.1")
        out, events = run(robot, clear_plan(), row_scene())
    finally:
        proc.terminate()
        proc.wait(10)
    assert out.completed == ("b0", "b1", "b2") and "REFUSED" in out.error
    assert [e.kind for e in events][-1] == "error"


def test_controller_hangs_up_on_a_flooding_console_and_serves_the_next() -> None:
    """5,000 blank lines to the reference controller: one BAD_REQUEST, then it closes that
    connection (no recursion, no endless error replies); a fresh connection is served."""
    with RobotController() as ctl:
        sock = socket.create_connection(ctl.address, timeout=2)
        conn = LineConn(sock)
        sock.sendall(b"\n" * 5000)
        err = conn.recv(2)
        assert err["type"] == "error" and err["code"] == "BAD_REQUEST" and "blank lines" in err["message"]
        with pytest.raises(ConnectionError):
            for _ in range(10):
                conn.recv(2)
        conn.close()
        out, _ = run(driver(ctl), clear_plan(("b0",)), row_scene())
    assert out.ok and out.completed == ("b0",)


# ---------------------------------------------------------------------- the run id
def step_line(plan: str, step: int, box: str, run: str | None) -> dict:
    msg = {"type": "step", "plan": plan, "step": step, "box": box, "frame": "robot_base",
           "grasp": {"point": [0.0, 0.0, 0.1], "approach": [0.0, 1.0, 0.0], "normal": [0.0, -1.0, 0.0]},
           "pull_distance": 0.3, "box_size": [0.2, 0.2, 0.2]}
    return msg if run is None else {**msg, "run": run}


def test_two_runs_of_one_plan_hash_both_execute_each_with_its_own_run_id() -> None:
    """A new capture that gives the same sequence is a new run: the reference controller executes it
    (it used to answer DUPLICATE_STEP, keyed by plan hash and step alone)."""
    plan, scene = clear_plan(), row_scene()
    with RobotController() as ctl:
        outs = []
        for _ in range(2):   # the console gives each run a fresh history of what this capture did
            robot = driver(ctl, history=StepHistory())
            outs.append((run(robot, plan, scene)[0], robot.last_run_id))
        hellos, steps = ctl.received("hello"), ctl.received("step")
        executed = ctl.executed
    (out1, run1), (out2, run2) = outs
    assert out1.ok and out2.ok, (out1.error, out2.error)
    assert run1 and run2 and run1 != run2
    assert [h["run"] for h in hellos] == [run1, run2]
    assert [(m["run"], m["step"]) for m in steps] == [(run1, i) for i in range(4)] + [(run2, i) for i in range(4)]
    assert executed == [(plan.content_hash(), i, f"b{i}") for i in range(4)] * 2


def test_a_repeated_step_within_one_run_is_refused() -> None:
    """Same run id, same step: DUPLICATE_STEP, on the same connection and on a reconnect; a step that
    names another run than its hello is a bad request; a console that sends no run id keeps the old
    keying by plan hash and step."""
    with RobotController() as ctl:
        def session(run_id: str | None) -> LineConn:
            conn = LineConn(socket.create_connection(ctl.address, timeout=2))
            hello = {"type": "hello", "protocol": "shelfpick.robot/1", "plan": "p1", "steps": 2}
            conn.send(hello if run_id is None else {**hello, "run": run_id})
            assert conn.recv(2)["type"] == "hello"
            return conn

        def ask(conn: LineConn, step: int, run_id: str | None) -> list[str]:
            conn.send(step_line("p1", step, f"b{step}", run_id))
            kinds = [conn.recv(2)]
            if kinds[0]["type"] == "ack":
                kinds.append(conn.recv(2))
            return [m["type"] if m["type"] != "error" else m["code"] for m in kinds]

        conn = session("run-A")
        assert ask(conn, 0, "run-A") == ["ack", "done"]
        assert ask(conn, 0, "run-A") == ["DUPLICATE_STEP"]
        assert ask(conn, 1, "run-B") == ["BAD_REQUEST"]             # not this connection's run
        conn.close()
        conn = session("run-A")                                    # a reconnect of the same run
        assert ask(conn, 0, "run-A") == ["DUPLICATE_STEP"]
        assert ask(conn, 1, "run-A") == ["ack", "done"]
        conn.close()
        conn = session("run-C")                                    # another run: done again
        assert ask(conn, 0, "run-C") == ["ack", "done"]
        conn.close()
        conn = session(None)                                       # no run id: keyed by plan and step
        assert ask(conn, 0, None) == ["ack", "done"]
        assert ask(conn, 0, None) == ["DUPLICATE_STEP"]
        conn.send({"type": "hello", "protocol": "shelfpick.robot/1", "run": 7})
        assert conn.recv(2)["code"] == "BAD_REQUEST"
        conn.close()
        assert len(ctl.executed) == 4     # run-A 0 and 1, run-C 0, the run-less 0


def test_the_driver_refused_as_duplicate_when_it_resends_within_its_run() -> None:
    """The robot's refusal is a second line of defence: a driver whose history was lost but whose run
    id is the same (a retry of one run) is refused before anything moves, and says so."""

    plan, scene = clear_plan(("b0", "b1")), row_scene()
    with RobotController() as ctl:
        first = driver(ctl, history=StepHistory())
        first.run_id = "s7-retry"
        assert run(first, plan, scene)[0].ok
        again = driver(ctl, history=StepHistory())
        again.run_id = "s7-retry"
        out, events = run(again, plan, scene)
        executed = ctl.executed
    assert not out.ok and "DUPLICATE_STEP" in out.error and out.completed == ()
    assert [e.kind for e in events] == ["error"] and out.steps[0]["status"] == "error"
    assert len(executed) == 2


def test_the_console_records_the_run_id_it_sends_and_a_new_capture_runs_again(tmp_path: Path) -> None:
    """Through the workflow and a real SQLite file: each run's start event holds the run id the
    reference controller received; the second capture of the same shelf (same plan hash) executes."""
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from test_workflow import PASS, CodeShelfSource, small_scene

    store = SessionStore(tmp_path / "runs.sqlite")
    with RobotController() as ctl:
        wf = Workflow(CodeShelfSource(small_scene()), store,
                      lambda truth, seed: open_robot(ctl.url, truth=truth, seed=seed), PASS, samples=2)
        done = []
        try:
            for _ in range(2):
                wf.capture()
                st = wf.plan("clear", wait=True)
                entry = st.plans["physics"]
                wf.approve(entry.hash, PASS, "sue", accept_risk=True)
                st = wf.execute(wait=True)
                st = wf.wait_robot(30)
                assert st.robot == "done", (st.error, st.outcome)
                done.append((st.session_id, entry.hash))
        finally:
            wf.close()
        steps = ctl.received("step")
    assert done[0][1] == done[1][1] and done[0][0] != done[1][0]
    recorded = []
    for sid, _ in done:
        starts = [e for e in store.load_session(sid).robot_events if e["kind"] == "start"]
        assert len(starts) == 1
        recorded.append(starts[0]["detail"]["robot_run"])
    store.close()
    assert recorded[0].startswith(f"s{done[0][0]}-") and recorded[0] != recorded[1]
    n = len(steps) // 2
    assert n > 0 and [m["run"] for m in steps] == [recorded[0]] * n + [recorded[1]] * n
