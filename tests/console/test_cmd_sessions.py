"""`shelfpick sessions` and `shelfpick replay` on a real database."""
from __future__ import annotations

from pathlib import Path

import pytest

from console.cli import main

from session_fixture import make_session


@pytest.fixture(scope="module")
def db(tmp_path_factory) -> tuple[Path, int]:
    path = tmp_path_factory.mktemp("cli") / "s.db"
    sid, _ = make_session(path)
    sid2, _ = make_session(path)
    return path, sid2


def test_sessions_lists_a_table(db, capsys) -> None:
    path, sid2 = db
    assert main(["sessions", "--db", str(path)]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:3] == ["ID", "STARTED", "(UTC)"]
    assert out[1].split()[0] == str(sid2) and out[2].split()[0] == str(sid2 - 1)  # newest first
    assert "demo:stack#0" in out[1] and "extract b0" in out[1] and out[1].rstrip().endswith("done")


def test_sessions_json_and_missing_db(db, tmp_path: Path, capsys, monkeypatch) -> None:
    import json

    path, _ = db
    assert main(["sessions", "--db", str(path), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert len(rows) == 2 and rows[0]["n_boxes"] == 3 and rows[0]["status"] == "done"
    monkeypatch.chdir(tmp_path)
    assert main(["sessions"]) == 2  # default data/shelfpick.db does not exist here
    assert "data/shelfpick.db: no session database" in capsys.readouterr().err


def test_replay_command_writes_the_page(db, tmp_path: Path, capsys) -> None:
    path, sid2 = db
    out = tmp_path / "x" / "replay.html"
    assert main(["replay", str(sid2), "--html", str(out), "--db", str(path)]) == 0
    assert out.is_file() and "data:image/png;base64," in out.read_text()
    assert f"session {sid2}: replay written" in capsys.readouterr().out
    assert main(["replay", "999", "--html", str(out), "--db", str(path)]) == 2
    assert "no session with id 999" in capsys.readouterr().err
