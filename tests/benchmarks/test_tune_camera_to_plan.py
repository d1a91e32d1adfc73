"""benchmarks/tune_camera_to_plan.py (issue 31): camera to plan on the tuning role. Held-out looks and
seeds outside the tuning shelves are refused; targets are seeded and seen; one real tuning shelf goes
from the generator's frame through perception and both planners to the judge."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from bench_scripts import JUDGE, load

tc = load("tune_camera_to_plan")


def test_held_out_looks_and_other_seeds_are_refused(capsys) -> None:
    assert tc.main(["--look", "printed", "--out", "/nonexistent/r.jsonl"]) == 2
    assert "printed" in capsys.readouterr().err
    assert tc.main(["--seeds", "31000-31060", "--out", "/nonexistent/r.jsonl"]) == 2
    assert "31060" in capsys.readouterr().err
    assert tc.main(["--seeds", "31a", "--out", "/nonexistent/r.jsonl"]) == 2
    assert "--seeds" in capsys.readouterr().err


def test_targets_are_seeded_and_only_boxes_the_camera_sees() -> None:
    truth = {"boxes": [{"id": f"b{i}"} for i in range(8)]}
    seen = {"b1", "b2", "b3", "b5", "b7"}
    a = tc.targets_of(truth, seen, 31000, 3)
    assert a == tc.targets_of(truth, seen, 31000, 3) and len(set(a)) == 3 and set(a) <= seen
    assert tc.targets_of(truth, {"b4"}, 31000, 3) == ["b4"]
    assert any(tc.targets_of(truth, seen, s, 3) != a for s in range(31001, 31010))


@pytest.mark.slow
@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_one_tuning_shelf_from_the_image_to_the_judge(tmp_path: Path) -> None:
    out = tmp_path / "rows.jsonl"
    argv = ["--judge-dir", str(JUDGE), "--look", "flat", "--seeds", "31000", "--targets", "1", "--out", str(out)]
    assert tc.main(argv) == 0
    (row,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert row["key"] == "flat|31000" and row["shelf"]["error"] == "" and row["shelf"]["perceived"] >= 1
    (task,) = row["tasks"]
    assert task["target"] in row["shelf"]["counted"]
    for which in ("physics", "highest_first", "true"):
        plan = task[which]
        if plan.get("error") != "target not perceived":
            assert plan["sequence"][-1] == task["target"] and "pybullet" in plan["judges"]
    assert "from the image, highest-first" in out.with_suffix(".md").read_text()
    assert tc.main(argv + ["--resume"]) == 0        # nothing left to run: the same row
    assert [json.loads(line) for line in out.read_text().splitlines()] == [row]
