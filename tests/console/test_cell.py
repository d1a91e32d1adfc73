"""`shelfpick console --cell cell.toml`: the cell file is read and checked before anything opens
(one line naming file, field and value; exit 2; no database created), optional libraries are
looked up before the server starts, and SIGTERM stops a robot run and closes the database
(a real subprocess, a real SQLite file)."""
from __future__ import annotations

import importlib.util
import queue
import signal
import sqlite3
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from shelfpick.console.cell import CellError, read_cell
from shelfpick.console.cli import main
from shelfpick.perception.scene import Camera

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent

GOOD = """
format = "shelfpick.cell/1"

[shelf]
width = 1.2
depth = 0.4
height = 1.8

[camera]
source = "demo"
file = "camera.json"

[perception]
segmenter = "depth"
catalogue = false

[robot]
url = "tcp://127.0.0.1:9000"
position = [0.6, 0.0, -0.2]
orientation = [1.0, 0.0, 0.0, 0.0]
step_timeout = 90

[safety]
samples = 4
seed = 7
db = "cell.db"
tolerance_displacement = 0.02
"""


def write_cell(tmp_path: Path, text: str = GOOD) -> Path:
    Camera(640, 480, 600.0, 600.0, 320.0, 240.0).save(tmp_path / "camera.json")
    (tmp_path / "cell.toml").write_text(textwrap.dedent(text))
    return tmp_path / "cell.toml"


def test_a_cell_file_is_read_with_paths_beside_it(tmp_path):
    cell = read_cell(write_cell(tmp_path))
    assert cell.shelf == (1.2, 0.4, 1.8) and cell.segmenter == "depth" and cell.catalogue is False
    assert cell.source_spec() == f"demo?camera={tmp_path / 'camera.json'}"
    assert cell.robot.startswith("tcp://127.0.0.1:9000?position=0.6,0.0,-0.2&orientation=1.0,0.0,0.0,0.0")
    assert "step_timeout=90.0" in cell.robot
    assert cell.safety == {"samples": 4, "seed": 7, "db": str(tmp_path / "cell.db"), "tolerance_displacement": 0.02}
    assert cell.tolerance().displacement == 0.02
    from shelfpick.console.robot.tcp import TcpRobot

    robot = TcpRobot.from_spec(cell.robot)          # the spec the console opens is one the driver takes
    assert robot.timeouts.step == 90.0


@pytest.mark.parametrize("old, new, field, value", [
    ("width = 1.2", "width = -1", "shelf.width", "-1"),
    ("depth = 0.4", 'depth = "deep"', "shelf.depth", "'deep'"),
    ('segmenter = "depth"', 'segmenter = "magic"', "perception.segmenter", "'magic'"),
    ("catalogue = false", 'catalogue = "no"', "perception.catalogue", "'no'"),
    ('url = "tcp://127.0.0.1:9000"', 'url = "http://robot:80"', "robot.url", "'http://robot:80'"),
    ('url = "tcp://127.0.0.1:9000"', 'url = "tcp://robot:9000?transform=x.json"', "robot.url", "transform=x.json"),
    ("orientation = [1.0, 0.0, 0.0, 0.0]", "orientation = [1.0, 1.0, 0.0, 0.0]", "robot.orientation", "1.4142"),
    ("position = [0.6, 0.0, -0.2]", "position = [0.6, 0.0]", "robot.position", "[0.6, 0.0]"),
    ("step_timeout = 90", "step_timeout = 0", "robot.step_timeout", "0"),
    ("samples = 4", "samples = 0", "safety.samples", "0"),
    ('file = "camera.json"', 'file = "nope.json"', "camera.file", "nope.json"),
    ('source = "demo"', 'source = "webcam"', "camera.source", "'webcam'"),
    ("[safety]", "[safty]", "safty", "unknown section"),
    ("seed = 7", "sed = 7", "safety.sed", "unknown key"),
    ("height = 1.8", "height = 1.8\nheight = 2", "", "not valid TOML"),
])
def test_a_wrong_value_is_one_line_naming_file_field_and_value_exit_2(tmp_path, capsys, old, new, field, value):
    path = write_cell(tmp_path, GOOD.replace(old, new))
    with pytest.raises(CellError):
        read_cell(path)
    rc = main(["console", "--cell", str(path), "--port", "0", "--no-capture"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert str(path) in err[0] and field in err[0] and value in err[0], err[0]
    assert not (tmp_path / "cell.db").exists()            # refused before the database was opened


def test_a_wrong_camera_file_named_by_the_cell_is_its_own_one_line_error(tmp_path, capsys):
    path = write_cell(tmp_path)
    (tmp_path / "camera.json").write_text('{"format": "shelfpick.camera/1", "width": 0}')
    assert main(["console", "--cell", str(path), "--port", "0", "--no-capture"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "camera.json" in err[0] and "width" in err[0]


@pytest.mark.skipif(importlib.util.find_spec("pyrealsense2") is not None, reason="pyrealsense2 is installed")
@pytest.mark.parametrize("how", ["option", "cell"])
def test_realsense_without_its_library_refuses_before_anything_starts(tmp_path, capsys, how):
    if how == "option":
        argv = ["console", "--source", "realsense", "--db", str(tmp_path / "cell.db")]
    else:
        argv = ["console", "--cell", str(write_cell(tmp_path, GOOD.replace('source = "demo"',
                                                                            'source = "realsense"')))]
    t0 = time.perf_counter()
    rc = main(argv + ["--port", "0", "--no-capture"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and "pyrealsense2" in err[0] and "shelfpick[realsense]" in err[0]
    assert ("camera.source" in err[0]) == (how == "cell")
    assert not (tmp_path / "cell.db").exists() and time.perf_counter() - t0 < 10


CHILD = textwrap.dedent("""
    import sys, threading, time
    sys.path[:0] = [{root!r}, {here!r}]
    from test_workflow import CodeShelfSource, small_scene, PASS
    from shelfpick.console import cmd_console
    from shelfpick.console.cli import build_parser, configure_logging
    args = build_parser().parse_args(["console", "--port", "0", "--db", {db!r}, "--robot", "sim?delay=30",
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
            print("READY", wf.state.session_id, flush=True)   # step 1 acknowledged; its pull takes 30 s
        except BaseException as exc:
            print("FAILED", repr(exc), flush=True)
            raise
    threading.Thread(target=drive, daemon=True).start()
    sys.exit(cmd_console.serve(parts, args))
""")


def test_sigterm_stops_the_robot_run_and_closes_the_database(tmp_path):
    from shelfpick.console.store.sessions import SessionStore

    db = tmp_path / "t.sqlite"
    code = CHILD.format(root=str(ROOT), here=str(HERE), db=str(db))
    err_file = tmp_path / "stderr.txt"             # a file, not a pipe nobody reads while waiting
    with err_file.open("w") as err_out:
        proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=err_out,
                                text=True, cwd=ROOT)
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(raw) for raw in proc.stdout], daemon=True).start()
    try:
        sid, seen, deadline = None, [], time.monotonic() + 120
        while sid is None and time.monotonic() < deadline and not any(x.startswith("FAILED") for x in seen):
            try:
                seen.append(lines.get(timeout=1))
            except queue.Empty:
                continue
            if seen[-1].startswith("READY"):
                sid = int(seen[-1].split()[1])
        assert sid is not None, f"stdout {seen!r}; stderr {err_file.read_text()}"
        # the URL line whole, though threads connected pybullet clients while it was printed
        assert any(x.startswith("shelfpick console: http") and x.endswith(".sqlite)\n") for x in seen), seen
        t0 = time.perf_counter()
        proc.send_signal(signal.SIGTERM)
        rc = proc.wait(60)
        stopped_in = time.perf_counter() - t0
        err = err_file.read_text()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert rc == 143, err
    assert stopped_in < 25, stopped_in                   # not the 30 s pull: the step was aborted
    assert "stopped by SIGTERM" in err
    assert not Path(str(db) + "-wal").exists() or Path(str(db) + "-wal").stat().st_size == 0  # closed cleanly
    open_runs = sqlite3.connect(db).execute("SELECT COUNT(*) FROM runs WHERE ended IS NULL").fetchone()[0]
    assert open_runs == 0
    store = SessionStore(db, readonly=True)
    rec = store.load_session(sid)
    stops = [e for e in rec.robot_events if e["kind"] == "stop"]
    assert stops and stops[0]["detail"]["who"] == "SIGTERM"
    assert rec.outcome is not None and not rec.outcome["ok"]
    store.close()


def test_the_example_cell_file_reads():
    cell = read_cell(ROOT / "examples" / "cell.toml")
    assert cell.robot == "sim" and cell.shelf == (1.0, 0.30, 1.60) and cell.safety["samples"] == 10


PLANNING = GOOD + """
[planning]
mass_kg = [0.5, 3.0]
friction = [0.6, 0.8]
pull_modes = ["lift"]
max_plan_risk = 0.02
"""


def test_the_planning_section_gives_the_sample_worlds_priors_and_the_plan_threshold(tmp_path):
    from shelfpick.planning.calibration import DEFAULT_MAX_PLAN_RISK
    from shelfpick.planning.uncertainty import Uncertainty

    priors = read_cell(write_cell(tmp_path, PLANNING)).priors()
    assert priors.max_plan_risk == 0.02
    model = priors.model()
    assert model.mass == (0.5, 3.0) and model.friction == (0.6, 0.8) and model.pull_modes == ("lift",)
    assert model.catalogue == Uncertainty().catalogue          # what the cell does not say stays the default
    default = read_cell(write_cell(tmp_path)).priors()          # no [planning]: the documented defaults
    assert default.max_plan_risk == DEFAULT_MAX_PLAN_RISK and default.model() == Uncertainty()


@pytest.mark.parametrize("old, new, field, value", [
    ("mass_kg = [0.5, 3.0]", "mass_kg = [3.0, 0.5]", "planning.mass_kg", "[3.0, 0.5]"),
    ("friction = [0.6, 0.8]", "friction = [0.6]", "planning.friction", "[0.6]"),
    ('pull_modes = ["lift"]', 'pull_modes = ["yank"]', "planning.pull_modes", "'yank'"),
    ("max_plan_risk = 0.02", "max_plan_risk = 1.5", "planning.max_plan_risk", "1.5"),
    ("max_plan_risk = 0.02", "max_risk = 0.02", "planning.max_risk", "unknown key"),
])
def test_a_wrong_planning_value_is_one_line_naming_the_field(tmp_path, old, new, field, value):
    with pytest.raises(CellError) as err:
        read_cell(write_cell(tmp_path, PLANNING.replace(old, new)))
    msg = str(err.value)
    assert "\n" not in msg and field in msg and value in msg, msg


def test_the_console_plans_with_the_cells_priors_and_threshold(tmp_path):
    """The cell's [planning] section reaches the console's planner: its sample worlds draw the
    cell's pull modes and its plans are gated with the cell's threshold (recorded in the plan)."""
    sys.path.insert(0, str(HERE))
    from test_workflow import PASS, CodeShelfSource, small_scene

    from shelfpick.console import cmd_console
    from shelfpick.console.cli import build_parser

    text = PLANNING.replace('url = "tcp://127.0.0.1:9000"', 'url = "sim"').replace(
        "position = [0.6, 0.0, -0.2]\norientation = [1.0, 0.0, 0.0, 0.0]\nstep_timeout = 90\n", "")
    args = build_parser().parse_args(["console", "--cell", str(write_cell(tmp_path, text)), "--port", "0",
                                      "--no-capture", "--samples", "2", "--supervisor-passphrase", PASS])
    parts = cmd_console.build(args)
    app, wf, store = parts[:3]
    try:
        assert wf.priors.max_plan_risk == 0.02 and wf.priors.model().pull_modes == ("lift",)
        wf.source = CodeShelfSource(small_scene())
        wf.capture()
        wf.plan("clear", wait=True)
        search = wf.state.plans["physics"].plan.extra["search"]
        assert search["max_plan_risk"] == 0.02 and search["plan_risk"]["max_plan_risk"] == 0.02
    finally:
        app.stop()          # (and the workflow with it)
        store.close()
