"""`shelfpick sessions` and `shelfpick replay` on a real database."""
from __future__ import annotations

from pathlib import Path

import pytest

from shelfpick.console.cli import main

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


def test_sessions_stats_predicted_risk_against_what_happened(tmp_path: Path, capsys) -> None:
    """One unverified session (2 steps predicted safe) and one run of the risky plan, looked at
    after each step: its safe step stood, its risky step collapsed b1 and the look saw it."""
    import json

    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.verify import compare

    from session_fixture import stack_scene

    path = tmp_path / "stats.db"
    make_session(path)
    sid, info = make_session(path)
    scene = stack_scene()
    ok = compare(scene.without(["b2"]), scene.without(["b2"]), 0, "b2").to_json()
    fell = compare(scene.without(["b2", "b0"]), scene.without(["b2", "b0", "b1"]), 1, "b0").to_json()
    assert ok["within"] and not fell["within"]
    with SessionStore(path) as store:
        h = info["heuristic"]                       # steps b2 (risk 0), b0 (risk 1.0)
        store.add_robot_event(sid, h, "done", 0, "b2", {"collapsed": []})
        store.add_verification(sid, h, "r1", ok, scene, scene)
        store.add_robot_event(sid, h, "done", 1, "b0", {"collapsed": ["b1"]})
        store.add_verification(sid, h, "r1", fell, scene, scene)
        store.set_outcome(sid, {"plan": h, "ok": False, "held": True})
    assert main(["sessions", "--db", str(path), "--stats", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    by = {r["risk"]: r for r in doc["by_risk"]}
    assert (by["0%"]["steps"], by["0%"]["verified"], by["0%"]["deviations"], by["0%"]["not_verified"]) == (5, 1, 0, 4)
    assert (by["50-100%"]["steps"], by["50-100%"]["robot_collapses"], by["50-100%"]["deviations"]) == (1, 1, 1)
    assert by["50-100%"]["deviation_rate"] == 1.0 and by["1-49%"]["steps"] == 0
    assert by["all"]["steps"] == 6 and doc["sessions"] == {"done": 1, "held": 1}
    assert main(["sessions", "--db", str(path), "--stats"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert out[0].split()[:2] == ["PREDICTED", "RISK"] and out[-1] == "sessions: done 1, held 1"
    assert out[3].split()[:5] == ["50-100%", "1", "1.0", "1", "1"]
