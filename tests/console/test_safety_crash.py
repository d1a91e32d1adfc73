"""kill -9 at each stage of a session, then a restart; read-only archives; a SQLite file that is
not ours; a database path that cannot exist. Real subprocesses, real SQLite files, the real CLI."""
from __future__ import annotations

import hashlib
import os
import sqlite3
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from shelfpick.console.cli import main
from safety_kit import fault, judge_session

ROOT = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent

CHILD = textwrap.dedent("""
    import sys, time
    sys.path[:0] = [{root!r}, {here!r}]
    from test_workflow import CodeShelfSource, small_scene, PASS
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from shelfpick.console.robot.drivers import open_robot
    stage = {stage!r}
    store = SessionStore({db!r})
    wf = Workflow(CodeShelfSource(small_scene()), store,
                  lambda truth, seed: open_robot("sim?delay=30", truth=truth, seed=seed), PASS, samples=2)
    def ready():
        print("READY", wf.state.session_id, flush=True)
        time.sleep(120)
    st = wf.capture()
    if stage == "captured": ready()
    wf.plan("clear", wait=True)
    if stage == "planned": ready()
    h = wf.state.plans["physics"].hash
    wf.approve(h, PASS, "sue")
    if stage == "approved": ready()
    acked = []
    wf.add_listener(lambda s: acked.append(1) if any(e.kind == "ack" for e in s.robot_events) else None)
    wf.execute()
    while not acked: time.sleep(0.01)
    ready()   # executing: step 1 acknowledged, its pull takes 30 s
""")


def kill_at(stage: str, db: Path) -> int:
    code = CHILD.format(root=str(ROOT), here=str(HERE), stage=stage, db=str(db))
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                            text=True, cwd=ROOT)
    try:
        line: list[str] = []
        for raw in proc.stdout:                  # pybullet prints a line of its own first
            if raw.startswith("READY"):
                line = raw.split()
                break
        assert line, f"child did not reach {stage}"
        proc.kill()               # SIGKILL: no atexit, no close, no outcome
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    fault()
    return int(line[1])


@pytest.mark.parametrize("stage, status", [("captured", "captured"), ("planned", "planned"),
                                           ("approved", "approved"), ("executing", "interrupted")])
def test_kill_9_at_each_stage_then_restart(tmp_path, stage, status):
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    db = tmp_path / "k.sqlite"
    sid = kill_at(stage, db)
    store = SessionStore(db)                       # the restart
    wf = Workflow(None, store, lambda t, s: None, "pw")
    rec = store.load_session(sid)
    assert rec.status == status
    open_runs = sqlite3.connect(db).execute("SELECT COUNT(*) FROM runs WHERE ended IS NULL").fetchone()[0]
    assert open_runs == 0
    if stage == "executing":
        unknown = [e for e in rec.robot_events if e["kind"] == "unknown"]
        assert [(e["step"], e["box"]) for e in unknown] == [(0, rec.outcome["sequence"][0])]
        assert rec.outcome["interrupted"] and not rec.outcome["ok"] and rec.outcome["completed"] == []
        assert wf.state.recovered and "interrupted" in wf.state.recovered[0]
        h = rec.outcome["plan"]
        assert store.step_states(sid, h)[0][0] == "unknown"
        judge_session(store, sid, [(h, 0)])
        # a second restart changes nothing more
        Workflow(None, store, lambda t, s: None, "pw")
        assert len([e for e in store.load_session(sid).robot_events if e["kind"] == "unknown"]) == 1
    else:
        assert not wf.state.recovered and rec.outcome is None
    store.close()


def test_a_live_console_run_is_not_taken_for_a_crash(tmp_path):
    """Two consoles on one database: the second one must not mark the first one's run interrupted."""
    from shelfpick.console.store.sessions import SessionStore

    from test_store import tiny_capture, tiny_scene

    db = tmp_path / "l.sqlite"
    a = SessionStore(db)
    sid = a.new_session("t", tiny_capture(), tiny_scene(), None, None)
    a.start_run(sid, "h", None, {})
    b = SessionStore(db)
    assert b.recover_interrupted() == []
    a.close()                                    # its console is gone now
    assert [r["session"] for r in b.recover_interrupted()] == [sid]
    b.close()


def sha(p: Path) -> str:
    return hashlib.sha256(p.read_bytes()).hexdigest()


def test_read_only_archive_lists_and_replays(tmp_path, capsys):
    from session_fixture import make_session

    db = tmp_path / "arch" / "s.db"
    sid, _ = make_session(db)
    before = {p.name: sha(p) for p in db.parent.iterdir() if p.is_file()}
    files = [db] + sorted((db.parent / "s.db.files").rglob("*"))
    for p in files:
        os.chmod(p, 0o555 if p.is_dir() else 0o444)
    os.chmod(db.parent, 0o555)
    fault()
    try:
        assert main(["sessions", "--db", str(db)]) == 0
        assert str(sid) in capsys.readouterr().out
        out = tmp_path / "r.html"
        assert main(["replay", str(sid), "--html", str(out), "--db", str(db)]) == 0
        assert out.is_file() and "data:image/png" in out.read_text()
    finally:
        os.chmod(db.parent, 0o755)
        for p in files:
            os.chmod(p, 0o755 if p.is_dir() else 0o644)
    assert sha(db) == before["s.db"]


def test_sessions_on_an_unrelated_sqlite_file_refuses_and_writes_nothing(tmp_path, capsys):
    db = tmp_path / "other.db"
    con = sqlite3.connect(db)
    con.execute("CREATE TABLE invoices(id INTEGER, total REAL)")
    con.execute("INSERT INTO invoices VALUES (1, 9.5)")
    con.commit()
    con.close()
    before = sha(db)
    fault(3)
    for argv in (["sessions", "--db", str(db)], ["replay", "1", "--html", str(tmp_path / "x.html"), "--db", str(db)],
                 ["console", "--db", str(db), "--port", "0", "--no-capture"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "not a shelfpick session database" in err[0] and "invoices" in err[0]
    assert sha(db) == before
    tables = {r[0] for r in sqlite3.connect(db).execute("SELECT name FROM sqlite_master")}
    assert tables == {"invoices"}
    assert not Path(str(db) + "-wal").exists() or Path(str(db) + "-wal").stat().st_size == 0


@pytest.mark.parametrize("cmd", ["console", "sessions"])
def test_a_database_path_that_cannot_exist_is_one_line(cmd, capsys):
    fault()
    argv = [cmd, "--db", "/proc/nope/x.db"] + (["--port", "0", "--no-capture"] if cmd == "console" else [])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "/proc/nope/x.db" in err[0] and "Traceback" not in err[0]


@pytest.mark.parametrize("pw", ["a", " ", "short pass  "])
def test_a_short_passphrase_beyond_localhost_refuses_to_start(pw, capsys, tmp_path):
    fault()
    argv = ["console", "--host", "0.0.0.0", "--port", "0", "--no-capture", "--supervisor-passphrase", pw,
            "--db", str(tmp_path / "p.db")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "at least 12 characters" in err[0]
    assert not (tmp_path / "p.db").exists()              # refused before anything was opened
