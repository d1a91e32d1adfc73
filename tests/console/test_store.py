"""The session store: a real SQLite file in WAL mode, images as PNGs beside it."""
from __future__ import annotations

import json
import os
import sqlite3
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest

from shelfpick.console.store.sessions import SessionStore, StoreError
from shelfpick.perception.capture import Capture
from shelfpick.perception.scene import Box, Camera, Scene, Shelf
from shelfpick.planning.plan import Plan, StepPrediction

ROOT = Path(__file__).resolve().parents[2]


def tiny_scene() -> Scene:
    return Scene(Shelf(1.0, 0.3, 1.6), (
        Box("b0", (0.2, 0.2, 0.2), (-0.2, 0.1, 0.1)),
        Box("b1", (0.2, 0.2, 0.2), (0.2, 0.1, 0.1)),
        Box("b2", (0.2, 0.2, 0.2), (-0.2, 0.1, 0.3))))


def tiny_capture(seed: int = 0) -> Capture:
    rng = np.random.default_rng(seed)
    cam = Camera(64, 48, 60.0, 60.0, 32.0, 24.0)
    rgb = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    depth = (rng.uniform(0.5, 2.0, (48, 64)) / 0.001).round().astype(np.float32) * 0.001
    masks = np.zeros((48, 64), np.uint16)
    masks[5:20, 5:30] = 1
    masks[25:40, 30:60] = 2
    return Capture(rgb, depth, cam, masks, {1: "b0", 2: "b1"})


def a_plan(planner: str = "physics") -> Plan:
    return Plan("extract", "b0", planner, ("b2", "b0"),
                (StepPrediction("b2", 0.0, 0.1, ()), StepPrediction("b0", 0.2, 0.0, ("b1",))),
                True, {"total": 1.5}, 7)


def test_round_trip_with_images(tmp_path: Path) -> None:
    db = tmp_path / "data" / "s.db"
    store = SessionStore(db)
    assert store.journal_mode() == "wal"
    cap = tiny_capture()
    overlay = np.full((48, 64, 3), 77, np.uint8)
    overlay[10, 10] = (255, 0, 0)
    sid = store.new_session("demo", cap, tiny_scene(), tiny_scene(), overlay,
                            {"warnings": ["one"], "timing": {"total": 0.3}})
    h = store.add_plan(sid, a_plan(), preview=[{"box": "b2", "frames": [[0.0, {"b0": [[0, 0, 0], [1, 0, 0, 0]]}]]}])
    h2 = store.add_plan(sid, a_plan("heuristic").__class__("extract", "b0", "heuristic", ("b0",)))
    store.add_decision(sid, h2, "reject", "sup", "too risky")
    store.add_decision(sid, h, "approve", "sup")
    store.add_robot_event(sid, h, "done", 0, "b2", {"collapsed": [], "displacement": {"b1": np.float64(0.01)}})
    store.set_outcome(sid, {"ok": True, "completed": ["b2", "b0"]})
    store.close()

    # the images really are files beside the database, paths stored relative
    files = sorted(p.name for p in (tmp_path / "data" / "s.db.files" / str(sid)).iterdir())
    assert {"rgb.png", "depth.png", "camera.json", "masks.png", "masks.json", "overlay.png"} <= set(files)
    raw = sqlite3.connect(db).execute("SELECT rgb FROM captures").fetchone()[0]
    assert not os.path.isabs(raw)

    rec = SessionStore(db).load_session(sid)
    assert rec.source == "demo" and rec.status == "done" and rec.task == "extract b0"
    assert np.array_equal(rec.capture.rgb, cap.rgb)
    assert np.allclose(rec.capture.depth, cap.depth, atol=1e-6)
    assert np.array_equal(rec.capture.masks, cap.masks) and dict(rec.capture.labels) == {1: "b0", 2: "b1"}
    assert np.array_equal(rec.overlay, overlay)
    assert rec.scene == tiny_scene() and rec.truth == tiny_scene()
    assert rec.perception["warnings"] == ["one"]
    assert [p.hash for p in rec.plans] == [h, h2] and rec.plan(h) == a_plan()
    assert rec.plans[0].preview[0]["box"] == "b2" and rec.plans[1].preview is None
    assert [(d["decision"], d["who"], d["reason"]) for d in rec.decisions] == [
        ("reject", "sup", "too risky"), ("approve", "sup", None)]
    assert rec.decisions[0]["at"].endswith("+00:00")
    assert rec.robot_events[0]["detail"]["displacement"]["b1"] == pytest.approx(0.01)
    assert rec.outcome == {"ok": True, "completed": ["b2", "b0"]}
    listed = SessionStore(db).list_sessions()
    assert listed[0]["id"] == sid and listed[0]["n_boxes"] == 3 and listed[0]["n_plans"] == 2


def test_bad_decision_and_unknown_session(tmp_path: Path) -> None:
    store = SessionStore(tmp_path / "s.db")
    sid = store.new_session("demo", tiny_capture(), tiny_scene(), None, None)
    with pytest.raises(StoreError, match="approve"):
        store.add_decision(sid, "x", "maybe", "sup")
    with pytest.raises(StoreError, match="no session with id 99"):
        store.add_plan(99, a_plan())
    with pytest.raises(StoreError, match="no session with id 99"):
        store.load_session(99)
    assert store.load_session(sid).truth is None


def test_committed_record_survives_kill_9(tmp_path: Path) -> None:
    db = tmp_path / "k.db"
    code = textwrap.dedent(f"""
        import sys, time
        sys.path.insert(0, {str(ROOT)!r}); sys.path.insert(0, {str(Path(__file__).parent)!r})
        from test_store import tiny_capture, tiny_scene, a_plan
        from shelfpick.console.store.sessions import SessionStore
        s = SessionStore({str(db)!r})
        sid = s.new_session("demo", tiny_capture(), tiny_scene(), None, None)
        h = s.add_plan(sid, a_plan())
        s.add_decision(sid, h, "approve", "sup")
        print(sid, h, flush=True)
        time.sleep(60)
    """)
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        line = proc.stdout.readline().split()
        assert line, "child wrote nothing"
        proc.kill()  # SIGKILL: no atexit, no close, no checkpoint
        proc.wait(10)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert Path(str(db) + "-wal").exists()  # the records live in the WAL, not yet checkpointed
    rec = SessionStore(db).load_session(int(line[0]))
    assert rec.plans[0].hash == line[1]
    assert rec.decisions[0]["decision"] == "approve" and rec.status == "approved"


def test_locked_database_is_a_clear_error(tmp_path: Path) -> None:
    db = tmp_path / "l.db"
    store = SessionStore(db, timeout=0.2)
    sid = store.new_session("demo", tiny_capture(), tiny_scene(), None, None)
    other = sqlite3.connect(db, isolation_level=None)
    other.execute("BEGIN EXCLUSIVE")
    try:
        t0 = time.monotonic()
        with pytest.raises(StoreError, match=r"l\.db: database is locked"):
            store.add_decision(sid, "abc", "approve", "sup")
        assert time.monotonic() - t0 < 3.0
    finally:
        other.execute("ROLLBACK")
        other.close()
    store.add_decision(sid, "abc", "approve", "sup")  # the store keeps working afterwards
    assert len(store.load_session(sid).decisions) == 1


def test_read_only_database_is_a_clear_error(tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    SessionStore(db).close()
    os.chmod(db, 0o444)
    try:
        with pytest.raises(StoreError, match=r"r\.db: database cannot be written"):
            SessionStore(db)
    finally:
        os.chmod(db, 0o644)


def test_immutable_database_file_is_a_clear_error(tmp_path: Path) -> None:
    """A file the OS refuses to write (chattr +i stops even root), not just a mode bit."""
    db = tmp_path / "i.db"
    SessionStore(db).close()
    if subprocess.run(["chattr", "+i", str(db)], capture_output=True).returncode != 0:
        pytest.skip("chattr +i not permitted here (the mode-bit test above covers read-only files)")
    try:
        with pytest.raises(StoreError, match=r"i\.db: database cannot be written"):
            SessionStore(db)
    finally:
        subprocess.run(["chattr", "-i", str(db)], check=True)


def test_unwritable_wal_is_a_clear_error(tmp_path: Path) -> None:
    """SQLite itself fails (the -wal file cannot be created): the message still names the file."""
    db = tmp_path / "w.db"
    SessionStore(db).close()
    (tmp_path / "w.db-wal").mkdir()
    with pytest.raises(StoreError, match=r"w\.db: "):
        SessionStore(db)


def test_concurrent_writers_from_threads(tmp_path: Path) -> None:
    from concurrent.futures import ThreadPoolExecutor

    store = SessionStore(tmp_path / "t.db")
    sid = store.new_session("demo", tiny_capture(), tiny_scene(), None, None)
    with ThreadPoolExecutor(8) as pool:
        list(pool.map(lambda i: store.add_robot_event(sid, "h", "done", i, f"b{i}", {"i": i}), range(40)))
    rec = store.load_session(sid)
    assert sorted(e["step"] for e in rec.robot_events) == list(range(40))
    assert json.loads(json.dumps(rec.robot_events[0]["detail"]))["i"] == rec.robot_events[0]["step"]


def test_owner_lock_says_which_console_is_alive(tmp_path: Path) -> None:
    """An open writable store holds `<db>.owners/<pid>-<token>.lock` (flock); close drops it, and a
    lock file a crash left unlocked is taken for a dead console and swept by recover_interrupted."""
    from shelfpick.console.store.owner import owner_alive, owners_dir

    db = tmp_path / "o.db"
    a = SessionStore(db)
    folder = owners_dir(db)
    [held] = list(folder.iterdir())
    assert owner_alive(a.owner, db)                       # held by an open store of this very process
    SessionStore(db, readonly=True).close()               # a reader holds no lock
    assert list(folder.iterdir()) == [held]
    a.close()
    assert list(folder.iterdir()) == [] and not owner_alive(a.owner, db)
    crashed = folder / f"{os.getpid() + 1}-deadbeef.lock"  # left by a console killed with -9
    crashed.write_text("")
    b = SessionStore(db)
    assert b.recover_interrupted() == [] and not crashed.exists()
    b.close()
