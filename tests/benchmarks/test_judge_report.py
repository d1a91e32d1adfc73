"""benchmarks/judge_report.py: the report's arithmetic on hand-made rows, and one real task judged
by the independent judge (../shared/judge, imported at run time) with both engines."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from bench_scripts import JUDGE, ROOT, load

jr = load("judge_report")


def _row(scene, risks, collapses, ok, safe, min_removals=None, exhaustive=False, planner="physics"):
    return {"key": f"0|{planner}|{scene}:b0", "scene": scene, "target": "b0", "kind": "structured", "noise": 0.0,
            "planner": planner, "exhaustive": exhaustive, "min_removals": min_removals, "plan_s": 0.5,
            "sequence": [f"b{i}" for i in range(len(risks))], "declared_safe": safe, "step_risk": risks,
            "judges": {"pybullet": {"ok": ok, "step_collapse": collapses},
                       "mujoco": {"ok": not ok, "step_collapse": collapses}}}


def test_reliability_counts_steps_up_to_the_first_collapse() -> None:
    rows = [_row("s00", [0.0, 0.1, 0.5, 0.0], [False, True, True, False], False, False),
            _row("s01", [0.0, 0.03], [False, False], True, True)]
    rel = {b["bin"]: b for b in jr.reliability(rows, "pybullet")}
    assert rel["0"]["steps"] == 2 and rel["0"]["collapses"] == 0          # s00 step 0, s01 step 0
    assert rel["(0, 0.05]"]["steps"] == 1 and rel["(0, 0.05]"]["observed"] == 0.0
    assert rel["(0.05, 0.1]"]["steps"] == 1 and rel["(0.05, 0.1]"]["observed"] == 1.0
    assert rel["(0.4, 1]"]["steps"] == 0                                   # after the first collapse: left out
    assert [jr.risk_bin(r) for r in (0.0, 1e-9, 0.05, 0.051, 0.2, 0.4, 0.41, 1.0)] == [0, 1, 1, 2, 3, 4, 5, 5]


def test_summary_figures_as_evaluate_prints_them() -> None:
    rows = [_row("s00", [0.0], [False], True, True, min_removals=1, exhaustive=True),
            _row("s01", [0.0, 0.2], [False, True], False, True, min_removals=1, exhaustive=True),
            _row("s02", [0.3], [True], False, False, exhaustive=True),
            _row("u00", [0.0, 0.0, 0.0], [False] * 3, True, False)]
    s = jr.engine_summary(rows, "pybullet")
    assert (s["ok"], s["tasks"], s["solvable_ok"], s["solvable"]) == (2, 4, 1, 2)
    assert (s["declared_safe_collapsed"], s["declared_safe"]) == (1, 2)
    assert (s["unsolvable_flagged"], s["unsolvable"]) == (1, 1)
    assert s["removed"] == 1.0 and s["removed_ratio"] == 1.0
    line = jr.evaluate_line("physics", 0.0, "pybullet", s)
    assert line == ("physics, noise 0.0 cm, pybullet judge: ok 2/4; exhaustively solvable tasks ok 1/2, removing "
                    "1.00 vs minimum 1.00; declared safe but collapsed 1/2; unsolvable tasks flagged unsafe 1/1")
    assert jr.engine_agreement(rows) == {"plans": 4, "pybullet_only": 2, "mujoco_only": 2}


def test_bad_arguments_exit_2(capsys, tmp_path: Path) -> None:
    assert jr.main(["--noise", "x"]) == 2
    assert "--noise" in capsys.readouterr().err
    assert jr.main(["--judge-dir", str(ROOT)]) == 2
    assert "--judge-dir" in capsys.readouterr().err
    for f in ("judge.py", "observe.py", "tasks.json"):    # a folder that passes the judge-dir check,
        (tmp_path / f).write_text("")                     # wherever the checkout lies
    assert jr.main(["--judge-dir", str(tmp_path), "--physics", '{"no_such_field": 1}']) == 2
    assert "--physics" in capsys.readouterr().err


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_one_task_judged_by_both_engines(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    out = tmp_path / "rows.jsonl"
    args = ["--judge-dir", str(JUDGE), "--tasks", "s00:b5", "--planners", "heuristic", "--engine", "both",
            "--out", str(out)]
    assert jr.main(args) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == 1 and rows[0]["key"] == "0|heuristic|s00:b5"
    assert set(rows[0]["judges"]) == {"pybullet", "mujoco"}
    assert len(rows[0]["step_risk"]) == len(rows[0]["sequence"]) == len(rows[0]["judges"]["pybullet"]["step_collapse"])
    assert out.with_suffix(".md").read_text().count("heuristic, noise 0.0 cm") == 2
    assert out.with_suffix(".png").stat().st_size > 1000
    # resumed: nothing left to run, the same rows
    assert jr.main(args + ["--resume"]) == 0
    assert [json.loads(line) for line in out.read_text().splitlines()] == rows


def test_clear_tasks_one_per_shelf() -> None:
    tasks = [{"scene": "s00", "target": "b1", "kind": "structured", "n_boxes": 8, "exhaustive": True,
              "min_removals": ["b1"]},
             {"scene": "s00", "target": "b2", "kind": "structured", "n_boxes": 8, "exhaustive": True,
              "min_removals": None},
             {"scene": "u01", "target": "b0", "kind": "unstructured", "n_boxes": 9, "exhaustive": False}]
    out = jr.clear_tasks(tasks)
    assert [(t["scene"], t["target"], t["kind"]) for t in out] == [("s00", None, "structured"),
                                                                  ("u01", None, "unstructured")]
    # a clearance has no exhaustive minimum: it never counts as solvable or unsolvable
    assert all(t["exhaustive"] is False and t["min_removals"] is None for t in out)
    assert jr.row_key(0.01, "physics", out[0]) == "0.01|physics|s00:clear"


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_a_clearance_and_a_plan_from_the_true_shelf_are_judged(tmp_path: Path) -> None:
    out = tmp_path / "rows.jsonl"
    assert jr.main(["--judge-dir", str(JUDGE), "--tasks", "s00", "--task", "clear", "--planners", "heuristic",
                    "--see-truth", "--out", str(out)]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    truth = json.loads((JUDGE / "scenes" / "s00.json").read_text())
    assert len(rows) == 1 and rows[0]["key"] == "0|heuristic|s00:clear"
    assert sorted(rows[0]["sequence"]) == sorted(b["id"] for b in truth["boxes"])   # every box
    assert json.loads(rows[0]["settings"])["see_truth"] is True


def test_physics_overrides_reach_the_planner() -> None:
    """`--physics` (a lever to measure) changes the planner's worlds, and the plan says so."""
    from benchmarks.judge_rows import make_timed_plan
    from shelfpick.perception.scene import Box, Scene, Shelf

    obs = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (0.0, 0.15, 0.1)),)).to_json()
    settings = {"samples": 1, "seed": 0, "risk": 0.0, "budget_s": None, "workers": 1}
    _, plain = make_timed_plan(obs, "b0", "heuristic", settings)
    _, lever = make_timed_plan(obs, "b0", "heuristic", {**settings, "physics": {"collapse_displacement": 0.03}})
    assert plain["provenance"]["physics"]["collapse_displacement"] == 0.02
    assert lever["provenance"]["physics"]["collapse_displacement"] == 0.03


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_a_physics_row_records_the_plans_predicted_success(tmp_path: Path) -> None:
    """The plan's chance that nothing goes wrong rides along (a plan-level reliability check
    reads it). Since issue 32 it is the calibrated one (1 - search.plan_risk.probability), not
    prod(1 - risk) over the steps' shares of failing worlds: a plan whose steps all held in every
    world still carries the calibrated chance of a collapse."""
    out = tmp_path / "rows.jsonl"
    assert jr.main(["--judge-dir", str(JUDGE), "--tasks", "s00:b5", "--planners", "physics", "--samples", "2",
                    "--out", str(out)]) == 0
    row = json.loads(out.read_text().splitlines()[0])
    assert 0.0 < row["success_prob"] < 1.0
    if all(r == 0.0 for r in row["step_risk"]):
        assert row["success_prob"] > 0.5
    # and the gate's evidence behind it: how many of the worlds it asked failed (issue 32's reliability)
    g = row["gate"]
    assert 0 <= g["failed_worlds"] <= g["worlds"] and g["worlds"] >= 1
    assert g["probability"] == pytest.approx(1.0 - row["success_prob"], abs=1e-3)
    assert row["declared_safe"] == (g["high"] < g["max_plan_risk"])
