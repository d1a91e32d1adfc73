"""benchmarks/judge_ceiling.py: the plans it tries, its argument errors, and one real task judged
by the independent judge (../shared/judge, imported at run time)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from bench_scripts import JUDGE, ROOT, load

jc = load("judge_ceiling")


def _box(i, x, z, h=0.2):
    return {"id": i, "size": [0.2, 0.2, h], "position": [x, 0.15, z], "orientation": [1, 0, 0, 0]}


SCENE = {"boxes": [_box("t", 0.0, 0.1), _box("a", 0.0, 0.3), _box("b", 0.0, 0.5),
                   _box("s", 0.25, 0.1), _box("under", 0.5, 0.05, 0.1)]}


def test_candidates_are_the_nearest_boxes_not_wholly_below_the_target():
    # nearest by centre: a (0.20 m), s (0.25), b (0.40), under (0.52; its top is above t's bottom)
    assert jc.candidates(SCENE, "t", 2) == ["a", "s"]
    assert jc.candidates(SCENE, "t", 9) == ["a", "s", "b", "under"]
    low = {"boxes": SCENE["boxes"][:1] + [_box("below", 0.0, -0.1)]}    # its top at t's bottom
    assert jc.candidates(low, "t", 5) == []


def test_plans_go_from_the_smallest_removal_set_up_top_first():
    out = jc.plans(SCENE, "t", 3, 2)
    assert out[0] == ["t"]
    assert all(p[-1] == "t" for p in out) and len(out) == 1 + 3 + 3
    assert ["b", "a", "t"] in out and ["a", "b", "t"] not in out      # higher box first


def test_bad_arguments_exit_2(capsys) -> None:
    assert jc.main(["--max-remove", "-1"]) == 2
    assert "--max-remove" in capsys.readouterr().err
    assert jc.main(["--judge-dir", str(ROOT)]) == 2
    assert "--judge-dir" in capsys.readouterr().err


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_a_free_target_holds_with_no_removal(tmp_path: Path) -> None:
    out = tmp_path / "rows.jsonl"
    assert jc.main(["--judge-dir", str(JUDGE), "--tasks", "s00:b5", "--out", str(out)]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert rows == [{"task": "s00:b5", "found": ["b5"], "tried": 1, "s": rows[0]["s"]}]


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_set_search_finds_the_judges_minimum_and_exhausts_an_unsolvable_task(tmp_path: Path) -> None:
    out = tmp_path / "rows.jsonl"
    assert jc.main(["--judge-dir", str(JUDGE), "--mode", "sets", "--tasks", "s00:b4,s14:b5",
                    "--out", str(out)]) == 0
    rows = {r["task"]: r for r in map(json.loads, out.read_text().splitlines())}
    # the judge's exhaustive search: s00:b4 needs b7 and b6 out first, s14:b5 has no collapse-free order
    assert sorted(rows["s00:b4"]["found"][:-1]) == ["b6", "b7"] and rows["s00:b4"]["found"][-1] == "b4"
    assert rows["s14:b5"]["found"] is None
    assert rows["s14:b5"]["reached"][-1] == 0 and len(rows["s14:b5"]["reached"]) >= 2   # searched to the end


def test_set_search_budget_must_be_positive(capsys) -> None:
    assert jc.main(["--mode", "sets", "--budget-s", "0"]) == 2
    assert "--budget-s" in capsys.readouterr().err


def test_set_search_engines_must_be_the_judges(capsys) -> None:
    assert jc.main(["--mode", "sets", "--engines", "bullet"]) == 2
    assert "--engines" in capsys.readouterr().err
