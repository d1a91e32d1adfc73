"""`shelfpick console` as a process (issue 30, items 6 and 8): Ctrl-C during a run stops it as
SIGTERM does (a `stop` record, an `abort` to the robot) and exits 130; a port out of range or a web
server thread that dies at start ends the command in one line instead of a hang. Real processes,
a real SQLite file, the reference robot controller on a real socket; every wait is bounded."""
from __future__ import annotations

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

from shelfpick.robotsim.controller import RobotController
from safety_kit import CONSOLE_RUN, fault, judge_stop

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent



def interrupt_a_run(tmp_path: Path, robot: str, sig: int) -> tuple[int, float, str, int]:
    """A console process runs a plan whose first step takes 30 s; `sig` arrives once it is
    acknowledged. (exit code, seconds from the signal to the exit, stderr, session id)"""
    db = tmp_path / "c.sqlite"
    code = CONSOLE_RUN.format(root=str(ROOT), here=str(HERE), db=str(db), robot=robot)
    err_file = tmp_path / "stderr.txt"
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
        assert sid is not None, f"stdout {seen!r}; stderr {err_file.read_text()[-3000:]}"
        t0 = time.monotonic()
        proc.send_signal(sig)
        rc = proc.wait(60)
        return rc, time.monotonic() - t0, err_file.read_text(), sid
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)


def test_ctrl_c_during_a_run_records_the_stop_aborts_the_step_and_exits_130(tmp_path):
    from shelfpick.console.store.sessions import SessionStore

    with RobotController(step_time=30.0) as ctl:
        fault()
        rc, took, err, sid = interrupt_a_run(tmp_path, ctl.url + "?heartbeat=0.2&heartbeat_timeout=5",
                                             signal.SIGINT)
        aborts = ctl.received("abort")
        steps = [m["step"] for m in ctl.received("step")]
    judge_stop(rc == 130 and bool(aborts))
    assert rc == 130, err
    assert took < 25, took                                   # not the 30 s step: it was aborted
    assert "stopped by SIGINT" in err and "Traceback" not in err, err
    assert steps == [0] and len(aborts) == 1 and aborts[0]["step"] == 0
    db = tmp_path / "c.sqlite"
    with sqlite3.connect(db) as c:
        assert c.execute("SELECT COUNT(*) FROM runs WHERE ended IS NULL").fetchone()[0] == 0
    store = SessionStore(db, readonly=True)
    rec = store.load_session(sid)
    stops = [e for e in rec.robot_events if e["kind"] == "stop"]
    assert [s["detail"]["who"] for s in stops] == ["SIGINT"] and stops[0]["detail"]["running"]
    assert rec.status == "stopped" and rec.outcome is not None and not rec.outcome["ok"]
    assert rec.outcome["stopped_by"] == "SIGINT"
    assert [s["status"] for s in rec.outcome["steps"]][0] == "aborted"
    store.close()


@pytest.mark.slow        # tests/console/test_cell.py covers SIGTERM in `make test`; this is the shared handler
def test_sigterm_still_exits_143_with_the_same_handler(tmp_path):
    """The shared handler keeps SIGTERM's contract (the sim robot: the stop is recorded, 143)."""
    from shelfpick.console.store.sessions import SessionStore

    rc, took, err, sid = interrupt_a_run(tmp_path, "sim?delay=30", signal.SIGTERM)
    assert rc == 143 and took < 25 and "stopped by SIGTERM" in err, err
    store = SessionStore(tmp_path / "c.sqlite", readonly=True)
    stops = [e for e in store.load_session(sid).robot_events if e["kind"] == "stop"]
    assert [s["detail"]["who"] for s in stops] == ["SIGTERM"]
    store.close()


def shelfpick(*argv: str, timeout: float = 90) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "shelfpick.console.cli", *argv], capture_output=True, text=True,
                          cwd=ROOT, timeout=timeout)


def test_a_port_out_of_range_is_one_line_and_exit_2(tmp_path):
    for port in ("70000", "-1", "65536"):
        out = shelfpick("console", "--port", port, "--db", str(tmp_path / "p.sqlite"), "--no-capture")
        err = out.stderr.strip().splitlines()
        assert out.returncode == 2 and len(err) == 1, out.stderr
        assert "--port" in err[0] and port in err[0] and "65535" in err[0], err[0]
    assert not (tmp_path / "p.sqlite").exists()               # refused before the database was opened


def test_an_address_this_machine_cannot_listen_on_is_one_line_and_exit_2(tmp_path):
    out = shelfpick("console", "--host", "192.0.2.1", "--port", "0", "--db", str(tmp_path / "h.sqlite"),
                    "--no-capture", "--supervisor-passphrase", "a long enough passphrase")
    err = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(err) == 1 and "192.0.2.1" in err[0], out.stderr


def test_a_server_thread_that_dies_at_start_ends_the_start_in_one_line(tmp_path):
    """viser's own server thread dies (an OverflowError on port 70000, past our check): the start
    ends in a bounded time with one line, instead of waiting for ever for the thread to listen."""
    code = textwrap.dedent(f"""
        import sys
        sys.path[:0] = [{str(ROOT)!r}]
        import viser
        from shelfpick.console.cmd_console import start_app
        from shelfpick.perception.errors import ShelfpickError
        try:
            start_app(lambda: viser.ViserServer(port=70000, verbose=False), "--port 70000", timeout=30)
        except ShelfpickError as exc:
            print("REFUSED", exc, flush=True)
            sys.exit(2)
        print("STARTED", flush=True)
    """)
    t0 = time.monotonic()
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=90)
    assert out.returncode == 2, (out.stdout, out.stderr)
    line = out.stdout.strip().splitlines()[-1]
    assert line.startswith("REFUSED the web server could not start") and "OverflowError" in line, line
    assert "Traceback" not in out.stderr and time.monotonic() - t0 < 60, out.stderr
