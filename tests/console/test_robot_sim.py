"""The simulated robot executes on the TRUE scene in real PyBullet and reports what really moved."""
from __future__ import annotations

import threading
from dataclasses import replace

import pytest

from shelfpick.console.robot.drivers import RobotError, RobotEvent, SimRobot, match_boxes, open_robot
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.plan import Plan


def stack_scene() -> Scene:
    """b1 stands on b0; b2 stands alone to the right."""
    return Scene(Shelf(1.0, 0.3, 1.6), (
        Box("b0", (0.2, 0.2, 0.2), (0.0, 0.12, 0.1)),
        Box("b1", (0.2, 0.2, 0.2), (0.0, 0.12, 0.3)),
        Box("b2", (0.2, 0.2, 0.2), (0.3, 0.12, 0.1))))


def run(robot: SimRobot, plan: Plan, scene: Scene, stop: threading.Event | None = None):
    events: list[RobotEvent] = []
    return robot.execute(plan, scene, events.append, stop or threading.Event()), events


def test_removing_the_box_under_another_reports_a_collapse() -> None:
    truth = stack_scene()
    robot = SimRobot(truth, seed=0)
    try:
        out, events = run(robot, Plan("extract", "b0", "heuristic", ("b2", "b0")), truth)
    finally:
        robot.close()
    assert not out.ok and out.needs_replan
    assert out.completed == ("b2", "b0")  # both pulled out...
    assert "collapsed: b1" in out.error    # ...but the box on top fell
    assert [e.kind for e in events] == ["ack", "done", "ack", "done", "error"]
    assert events[1].detail["collapsed"] == []
    assert events[3].detail["collapsed"] == ["b1"] and events[4].detail["code"] == "COLLAPSE"
    assert out.steps[1]["detail"]["displacement"]["b1"] > 0.05


def test_safe_order_is_ok_and_the_world_persists() -> None:
    truth = stack_scene()
    robot = SimRobot(truth, seed=1)
    try:
        out, events = run(robot, Plan("extract", "b0", "physics", ("b1", "b0")), truth)
        assert out.ok and out.error is None and out.completed == ("b1", "b0")
        assert all(not e.detail.get("collapsed") for e in events if e.kind == "done")
        assert robot.world().ids == ("b2",)  # the robot's shelf keeps what it did
        out2, events2 = run(robot, Plan("extract", "b1", "physics", ("b1",)), truth)
        assert not out2.ok and events2[0].detail["code"] == "NO_BOX_AT_GRASP"
    finally:
        robot.close()


def test_perceived_ids_and_depths_may_differ_from_the_truth() -> None:
    truth = stack_scene()
    rename = {"b0": "p7", "b1": "p3", "b2": "p0"}
    perceived = truth.with_boxes(replace(b, id=rename[b.id]) for b in truth.boxes).hide_depths(0.05)
    assert match_boxes(perceived, truth) == {"p7": "b0", "p3": "b1", "p0": "b2"}
    robot = SimRobot(truth, seed=0)
    try:
        out, events = run(robot, Plan("extract", "p7", "physics", ("p3", "p7")), perceived)
    finally:
        robot.close()
    assert out.ok and out.completed == ("p3", "p7")
    assert [e.detail.get("true_box") for e in events if e.kind == "done"] == ["b1", "b0"]


def test_stop_between_steps_and_no_resend_of_completed_steps() -> None:
    truth = stack_scene()
    plan = Plan("clear", None, "physics", ("b2", "b1", "b0"))
    stop = threading.Event()
    robot = SimRobot(truth, seed=0)
    try:
        events: list[RobotEvent] = []

        def on_event(ev: RobotEvent) -> None:
            events.append(ev)
            if ev.kind == "done":
                stop.set()

        out = robot.execute(plan, truth, on_event, stop)
        assert out.completed == ("b2",) and not out.ok and "stopped" in out.error
        assert events[-1].kind == "aborted" and events[-1].step == 1
        out2, events2 = run(robot, plan, truth)
    finally:
        robot.close()
    assert out2.ok and out2.completed == ("b2", "b1", "b0")
    assert [s["status"] for s in out2.steps] == ["skipped", "done", "done"]
    assert [e.step for e in events2 if e.kind == "ack"] == [1, 2]


def test_open_robot_sim_spec() -> None:
    r = open_robot("sim?delay=0.25", truth=stack_scene(), seed=3)
    assert isinstance(r, SimRobot) and r.step_delay == 0.25 and r.seed == 3 and r.name == "sim"
    with pytest.raises(RobotError, match="unknown option 'speed'"):
        open_robot("sim?speed=2")
    with pytest.raises(RobotError, match="delay: expected a number"):
        open_robot("sim?delay=fast")


HOSTILE = "<img src=x onerror=alert(1)>"


def test_repairs_of_the_true_world_are_a_note_event_once_per_world() -> None:
    """A true shelf that does not stand as given (a box floating 10 cm) is adjusted by the physics;
    the robot says so in a `note` event before the first step, not only on stderr."""
    truth = stack_scene().with_boxes(list(stack_scene().boxes) + [Box(HOSTILE, (0.1, 0.1, 0.1), (-0.3, 0.12, 0.15))])
    robot = SimRobot(truth, seed=0)
    try:
        with pytest.warns(UserWarning):
            out, events = run(robot, Plan("extract", "b2", "physics", ("b2",)), truth)
        out2, events2 = run(robot, Plan("extract", "b1", "physics", ("b1",)), truth)   # same world: told once
    finally:
        robot.close()
    assert out.ok and [e.kind for e in events] == ["note", "ack", "done"]
    note = events[0]
    assert note.step is None and note.box is None and note.detail["code"] == "WORLD_REPAIRED"
    [repair] = note.detail["repairs"]
    assert repair.startswith(f"box {HOSTILE!r} dropped onto its support: moved 0.1")
    assert "true shelf did not stand as given" in note.detail["message"] and HOSTILE in note.detail["message"]
    assert out2.ok and "note" not in [e.kind for e in events2]
    standing = SimRobot(stack_scene(), seed=0)
    try:
        out3, events3 = run(standing, Plan("extract", "b2", "physics", ("b2",)), stack_scene())
    finally:
        standing.close()
    assert out3.ok and [e.kind for e in events3] == ["ack", "done"]    # nothing repaired, nothing said


class _FloatingTruthSource:
    """The camera sees three standing boxes; the true shelf also holds a box floating out of view."""

    name = "floating-truth"

    def __init__(self) -> None:
        from test_workflow import small_scene

        self.scene = small_scene()
        self.truth = self.scene.with_boxes(list(self.scene.boxes) + [
            Box(HOSTILE, (0.08, 0.1, 0.08), (0.45, 0.2, 0.5))])
        self.n = 0

    def capture(self):
        from shelfpick.console.sources import Frame
        from shelfpick.perception.render import render

        self.n += 1
        return Frame(render(self.scene, seed=2), self.truth, f"floating-truth-{self.n}")


def test_the_console_stores_and_shows_the_robot_world_repairs_escaped(tmp_path) -> None:
    """Through the workflow and a real SQLite file: the note is a stored robot event of the run and
    reaches the page's robot panel as literal text (no tag)."""
    from shelfpick.console.web.app import robot_markdown
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from test_workflow import PASS, sim_factory

    store = SessionStore(tmp_path / "repairs.sqlite")
    wf = Workflow(_FloatingTruthSource(), store, sim_factory(), PASS, samples=2, seed=0)
    try:
        wf.capture()
        st = wf.plan("clear", wait=True)
        entry = st.plans["physics"]
        wf.approve(entry.hash, PASS, "sue", accept_risk=True)
        with pytest.warns(UserWarning):
            wf.execute(wait=True)
        st = wf.wait_robot(30)
        stored = [e for e in store.load_session(st.session_id).robot_events if e["kind"] == "note"]
    finally:
        wf.close()
        store.close()
    notes = [e for e in st.robot_events if e.kind == "note"]
    assert len(notes) == 1 and len(stored) == 1
    assert stored[0]["detail"]["code"] == "WORLD_REPAIRED" and HOSTILE in stored[0]["detail"]["repairs"][0]
    assert stored[0]["step"] is None and stored[0]["plan_hash"] == entry.hash
    page = robot_markdown(st)
    assert "- note: " in page and "dropped onto its support" in page
    assert "<img" not in page and "&#60;img src&#61;x onerror&#61;alert" in page
