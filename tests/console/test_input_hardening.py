"""The console's commands against hostile or clumsy input (issue 30): `replay` and `sessions` on a
damaged archive, replay paths out of the store, read-only opens that leave nothing behind, the
--robot URL and the cell file checked by one validator, bounds on --samples and the cell file
itself. Real SQLite files, real subprocesses where the exit matters."""
from __future__ import annotations

import argparse
import os
import shutil
import sqlite3
import subprocess
import sys
from pathlib import Path

import pytest

from shelfpick.console.cell import CellError, check_robot_spec, read_cell
from shelfpick.console.cli import main

from session_fixture import make_session

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def archive(tmp_path_factory) -> tuple[Path, int]:
    path = tmp_path_factory.mktemp("archive") / "s.db"
    sid, _ = make_session(path)
    return path, sid


def copy_of(archive: tuple[Path, int], tmp_path: Path) -> Path:
    src, _ = archive
    tmp_path.mkdir(parents=True, exist_ok=True)
    dst = tmp_path / "s.db"
    shutil.copy(src, dst)
    shutil.copytree(src.with_name(src.name + ".files"), dst.with_name(dst.name + ".files"))
    return dst


def poke(db: Path, sql: str, args: tuple = ()) -> None:
    con = sqlite3.connect(db)
    con.execute(sql, args)
    con.commit()
    con.close()


def one_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


def test_replay_of_an_id_beyond_sqlite_integers_is_one_line(archive, tmp_path: Path, capsys) -> None:
    db, _ = archive
    rc = main(["replay", "1180591620717411303424", "--html", str(tmp_path / "r.html"), "--db", str(db)])
    assert rc == 2 and "id: expected a session id from 1 to 9223372036854775807" in one_line(capsys)


@pytest.mark.parametrize("damage", ["not json", "[" * 100_000 + "]" * 100_000])
@pytest.mark.parametrize("command", ["replay", "sessions --stats"])
def test_stored_records_that_are_not_json_or_too_deep_are_one_line(archive, tmp_path: Path, capsys,
                                                                    damage: str, command: str) -> None:
    db = copy_of(archive, tmp_path)
    poke(db, "UPDATE plans SET plan=?", (damage,))
    argv = (["replay", str(archive[1]), "--html", str(tmp_path / "r.html")] if command == "replay"
            else ["sessions", "--stats"]) + ["--db", str(db)]
    assert main(argv) == 2
    line = one_line(capsys)
    assert str(db) in line and ("cannot be read" in line or "nested too deep" in line)
    assert not (tmp_path / "r.html").exists()


@pytest.mark.parametrize("where", ["../outside.png", "s.db.files/../../outside.png", "/ABSOLUTE/outside.png"])
def test_replay_reads_no_file_outside_the_session_store(archive, tmp_path: Path, capsys, where: str) -> None:
    import cv2
    import numpy as np

    db = copy_of(archive, tmp_path / "store")
    secret = tmp_path / "outside.png"
    marker = np.zeros((40, 40, 3), np.uint8)
    marker[:, :, 2] = 255
    cv2.imwrite(str(secret), marker)
    stored = where.replace("/ABSOLUTE", str(tmp_path)) if where.startswith("/") else where
    assert (db.parent / stored).resolve() == secret.resolve()       # the path does lead to the secret
    poke(db, "UPDATE captures SET overlay=?", (stored,))
    out = tmp_path / "r.html"
    assert main(["replay", str(archive[1]), "--html", str(out), "--db", str(db)]) == 0
    page = out.read_text()
    from shelfpick.console.web.replay import png_data_uri

    assert png_data_uri(cv2.cvtColor(marker, cv2.COLOR_BGR2RGB)) not in page
    assert "outside s.db.files/: not read" in page
    capsys.readouterr()


def test_a_huge_stored_overlay_is_not_decoded_and_the_session_still_replays(archive, tmp_path: Path,
                                                                            capsys) -> None:
    import struct
    import zlib

    db = copy_of(archive, tmp_path)
    overlay = db.with_name(db.name + ".files") / str(archive[1]) / "overlay.png"

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    overlay.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 30000, 30000, 8, 2, 0, 0, 0))
                        + chunk(b"IDAT", zlib.compress(b"\0" * 4096)) + chunk(b"IEND", b""))
    out = tmp_path / "r.html"
    assert main(["replay", str(archive[1]), "--html", str(out), "--db", str(db)]) == 0
    assert "overlay.png (not read: image of more than 40000000 pixels" in out.read_text()
    capsys.readouterr()


def test_read_only_commands_leave_no_wal_or_shm_beside_an_archive(archive, tmp_path: Path, capsys) -> None:
    db = copy_of(archive, tmp_path)
    side = [db.with_name(db.name + s) for s in ("-wal", "-shm")]
    assert not any(p.exists() for p in side)
    assert main(["sessions", "--db", str(db)]) == 0
    assert main(["sessions", "--stats", "--db", str(db)]) == 0
    assert main(["replay", str(archive[1]), "--html", str(tmp_path / "r.html"), "--db", str(db)]) == 0
    assert [p.name for p in side if p.exists()] == []
    capsys.readouterr()


def test_a_live_wal_is_still_read(archive, tmp_path: Path, capsys) -> None:
    """A console holding the database (its -wal present, commits not yet checkpointed) is read with
    what it committed, not the stale main file."""
    db = copy_of(archive, tmp_path)
    holder = sqlite3.connect(db)
    holder.execute("PRAGMA journal_mode=WAL")
    holder.execute("PRAGMA wal_autocheckpoint=0")
    holder.execute("UPDATE sessions SET source='held-by-a-console'")
    holder.commit()
    try:
        assert db.with_name(db.name + "-wal").exists()
        assert main(["sessions", "--db", str(db), "--json"]) == 0
        assert "held-by-a-console" in capsys.readouterr().out
    finally:
        holder.close()


# ---------------------------------------------------------------- the robot spec: one validator
@pytest.mark.parametrize("spec, says", [
    ("tcp://[::1:9000", "expected sim or tcp://HOST:PORT"),
    ("tcp://127.0.0.1:9000?heartbeat=0", "heartbeat: expected a number in [0.001, 3600]"),
    ("tcp://127.0.0.1:9000?step_timeout=1e308", "step_timeout: expected a number in [0.001, 3600]"),
    ("sim?delay=1e308", "delay: expected a number in [0, 600]"),
    ("sim?seed=-1", "seed: expected a number"),
    ("sim?bogus=1", "bogus: unknown option"),
    ("tcp://127.0.0.1:99999", "expected sim or tcp://HOST:PORT"),
    ("sim\x1b[2J", "printable"),
])
def test_robot_specs_get_the_cell_files_bounds(spec: str, says: str) -> None:
    with pytest.raises(CellError, match=says.replace("[", r"\[").replace("]", r"\]")):
        check_robot_spec(spec)


def test_a_scheme_is_case_blind_on_the_command_line_as_in_the_cell_file(tmp_path: Path) -> None:
    assert check_robot_spec(" TCP://127.0.0.1:9000?step_timeout=5 ") == "tcp://127.0.0.1:9000?step_timeout=5"
    assert check_robot_spec("Tcp://[::1]:9000") == "tcp://[::1]:9000"
    cell = tmp_path / "cell.toml"
    cell.write_text('[robot]\nurl = "TCP://127.0.0.1:9000"\n')
    assert read_cell(cell).robot == "tcp://127.0.0.1:9000"
    with pytest.raises(CellError, match="expected sim or tcp://HOST:PORT"):
        check_robot_spec("TCPX://127.0.0.1:9000")


def test_the_cell_file_refuses_what_the_url_refuses(tmp_path: Path) -> None:
    cell = tmp_path / "cell.toml"
    cell.write_text('[robot]\nurl = "tcp://127.0.0.1:9000"\nheartbeat = 0\n')
    with pytest.raises(CellError, match=r"robot.heartbeat: expected a number in \[0.001, 3600\]"):
        read_cell(cell)
    cell.write_text('[robot]\nurl = "tcp://[::1:9000"\n')
    with pytest.raises(CellError, match="robot.url"):
        read_cell(cell)
    cell.write_text('[robot]\nurl = "tcp://[::1]:9000"\nstep_timeout = 60\n')
    spec = read_cell(cell).robot
    assert spec == "tcp://[::1]:9000?step_timeout=60.0" and check_robot_spec(spec) == spec


def test_the_robot_drivers_take_the_same_bounds() -> None:
    from shelfpick.console.robot.drivers import RobotError, open_robot

    with pytest.raises(RobotError, match=r"delay: expected a number in \[0, 600\]"):
        open_robot("sim?delay=1e308")
    with pytest.raises(RobotError, match=r"heartbeat: expected a number in \[0.001, 3600\]"):
        open_robot("tcp://127.0.0.1:9000?heartbeat=0")


@pytest.mark.parametrize("argv, says", [
    (["--robot", "tcp://[::1:9000"], "--robot: expected sim or tcp://HOST:PORT"),
    (["--robot", "sim?delay=1e308"], "--robot: delay"),
    (["--samples", "1000000000"], "--samples: must be from 1 to 1000"),
    (["--workers", "100000"], "--workers: must be from 1 to 256"),
])
def test_console_refuses_before_opening_anything(tmp_path: Path, argv: list[str], says: str) -> None:
    db = tmp_path / "c.db"
    p = subprocess.run([sys.executable, "-m", "shelfpick.console.cli", "console", "--port", "0", "--no-capture",
                        "--db", str(db), *argv], cwd=ROOT, capture_output=True, text=True, timeout=60)
    lines = [ln for ln in p.stderr.splitlines() if ln.strip()]
    assert p.returncode == 2 and len(lines) == 1 and says in lines[0], p.stderr
    assert not db.exists()


def test_a_cell_file_that_is_a_link_to_dev_zero_is_refused_before_reading(tmp_path: Path) -> None:
    link = tmp_path / "cell.toml"
    link.symlink_to("/dev/zero")
    with pytest.raises(CellError, match="not a regular file"):
        read_cell(link)
    big = tmp_path / "big.toml"
    with open(big, "wb") as f:
        f.truncate(2 << 20)
    with pytest.raises(CellError, match="a cell file is at most"):
        read_cell(big)


def test_console_settings_from_the_cell_keep_their_bounds(tmp_path: Path) -> None:
    from shelfpick.console.cmd_console import build
    from shelfpick.perception.errors import ShelfpickError

    args = argparse.Namespace(cell=None, source=None, host=None, port=0, db=str(tmp_path / "c.db"), robot=None,
                              supervisor_passphrase=None, samples=10**9, seed=None, workers=None, no_capture=True)
    with pytest.raises(ShelfpickError, match="--samples: must be from 1 to 1000"):
        build(args)
    assert not (tmp_path / "c.db").exists()


def test_bad_box_ids_are_never_echoed_raw(tmp_path: Path, capsys) -> None:
    import json

    doc = {"format": "shelfpick.scene/1", "shelf": {"width": 1.0, "depth": 0.3, "height": 1.6},
           "boxes": [{"id": "\x1b]0;pwned\x07", "size": [0.2, 0.2, 0.2], "position": [0, 0.12, 0.1]}]}
    (tmp_path / "s.json").write_text(json.dumps(doc))
    assert main(["plan", str(tmp_path / "s.json"), "--task", "clear", "--samples", "1"]) == 2
    line = one_line(capsys)
    assert "\x1b" not in line and "\\x1b" in line


def test_argparse_errors_are_one_line(capsys) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["replay", "not-a-number", "--html", "x.html"])
    assert exc.value.code == 2
    line = one_line(capsys)
    assert "shelfpick replay: error: argument id: invalid int value: 'not-a-number'" in line


def test_plan_into_a_closed_pipe_exits_quietly(tmp_path: Path) -> None:
    import json

    doc = {"format": "shelfpick.scene/1", "shelf": {"width": 1.0, "depth": 0.3, "height": 1.6},
           "boxes": [{"id": f"b{i}", "size": [0.2, 0.2, 0.2], "position": [-0.3 + 0.3 * i, 0.12, 0.1]}
                     for i in range(3)]}
    (tmp_path / "s.json").write_text(json.dumps(doc))
    env = {**os.environ, "PYTHONUNBUFFERED": "0"}
    argv = [sys.executable, "-m", "shelfpick.console.cli", "plan", str(tmp_path / "s.json"), "--task", "clear", "--samples",
            "1", "--planner", "heuristic"]
    # the reader gone before anything is written (`| head -c 0`): every write meets a closed pipe
    r, w = os.pipe()
    os.close(r)
    try:
        p0 = subprocess.run(argv, cwd=ROOT, env=env, stdout=w, stderr=subprocess.PIPE, text=True, timeout=60)
    finally:
        os.close(w)
    assert p0.returncode == 141 and p0.stderr.strip() == "", (p0.returncode, p0.stderr)
    for _ in range(3):                            # `| head -c 100`: the reader goes after 100 bytes
        p = subprocess.Popen(argv, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        assert p.stdout is not None and p.stderr is not None
        head = p.stdout.read(100)
        p.stdout.close()                          # what `| head -c 100` does
        err = p.stderr.read().decode()
        rc = p.wait(timeout=60)
        assert len(head) == 100
        assert "Traceback" not in err and "BrokenPipe" not in err and "Exception ignored" not in err, err
        assert rc in (0, 141), (rc, err)
