"""The simulated robot executes on the TRUE scene in real PyBullet and reports what really moved."""
from __future__ import annotations

import threading
from dataclasses import replace

import pytest

from console.robot import RobotError, RobotEvent, SimRobot, match_boxes, open_robot
from perception.scene import Box, Scene, Shelf
from planning.plan import Plan


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
