"""examples/: the Python-API script runs and plans, and the minimal socket controller speaks the
protocol with the console's real TCP driver (real sockets, a real subprocess)."""
from __future__ import annotations

import json
import subprocess
import sys
import threading
from pathlib import Path

import pytest

from shelfpick.console.robot.tcp import TcpRobot
from shelfpick.console.robot.base import StepHistory
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.plan import Plan

ROOT = Path(__file__).resolve().parents[2]
EXAMPLES = ROOT / "examples"


def test_the_python_api_example_perceives_plans_and_executes():
    proc = subprocess.run([sys.executable, str(EXAMPLES / "plan_from_python.py"), "--samples", "2"],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout[proc.stdout.index("{"):])   # pybullet's renderer may print argv[0]= first
    assert doc["boxes_seen"] == doc["boxes_true"] == 6
    for planner in ("physics", "heuristic"):
        assert doc[planner]["sequence"][-1] == doc["target"]
    assert doc["physics"]["succeeded"] is True and "held" not in doc["physics"]
    assert len(doc["physics"]["sequence"]) <= len(doc["heuristic"]["sequence"])


def driver(port: int, run_id: str, query: str = "") -> TcpRobot:
    """The console's TCP driver with a history of its own (the console seeds one per run)."""
    spec = TcpRobot.from_spec(f"tcp://127.0.0.1:{port}{query}")
    robot = TcpRobot(spec.host, spec.port, spec.transform, spec.timeouts, history=StepHistory())
    robot.run_id = run_id
    return robot


def tiny() -> tuple[Scene, Plan]:
    scene = Scene(Shelf(), (Box("a", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)), Box("b", (0.2, 0.2, 0.2), (0.0, 0.1, 0.3))))
    return scene, Plan("extract", "a", "physics", ("b", "a"))


@pytest.fixture()
def controller(request):
    step_time = getattr(request, "param", 0.1)
    proc = subprocess.Popen([sys.executable, str(EXAMPLES / "robot_controller.py"), "--port", "0",
                             "--step-time", str(step_time)], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    line = proc.stdout.readline()
    assert line.startswith("listening on"), line
    yield int(line.rsplit(":", 1)[1])
    proc.kill()
    proc.wait(10)


def test_the_example_controller_executes_a_plan_and_refuses_a_repeated_step(controller):
    scene, plan = tiny()
    robot = driver(controller, "s1-example")
    events = []
    out = robot.execute(plan, scene, events.append, threading.Event())
    assert out.ok and out.completed == ("b", "a"), out
    assert [e.kind for e in events if e.kind in ("ack", "done")] == ["ack", "done", "ack", "done"]
    again = driver(controller, "s1-example")      # a console that forgot what it sent: same run id
    out2 = again.execute(plan, scene, lambda e: None, threading.Event())
    assert not out2.ok and "DUPLICATE_STEP" in (out2.error or "")
    fresh = driver(controller, "s2-example")      # a new capture's run of the same plan executes
    assert fresh.execute(plan, scene, lambda e: None, threading.Event()).ok


@pytest.mark.parametrize("controller", [30.0], indirect=True)
def test_a_stop_aborts_the_example_controllers_running_step(controller):
    scene, plan = tiny()
    robot = driver(controller, "s3-example", "?heartbeat=0.1")
    stop = threading.Event()

    def on_event(ev):
        if ev.kind == "ack":
            threading.Timer(0.5, stop.set).start()     # pings answered meanwhile, then Stop
    out = robot.execute(plan, scene, on_event, stop)
    assert not out.ok and out.completed == ()
    assert out.steps[0]["status"] == "aborted", out.steps
