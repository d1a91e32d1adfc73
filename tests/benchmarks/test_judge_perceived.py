"""benchmarks/judge_perceived.py: the id translation, bad arguments, and one real task (s00:b5) rendered,
perceived, planned twice and judged by the independent judge (../shared/judge, imported at run time)."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from bench_scripts import JUDGE, ROOT, load

jp = load("judge_perceived")


def test_translate_keeps_steps_aligned_and_flags_boxes_that_are_no_true_box() -> None:
    seq, failed = jp.translate(["p2", "p9", "p0"], {"p0": "b5", "p2": "b1"})
    assert seq == ["b1", jp.UNMAPPED + "p9", "b5"] and failed == [1]


def test_bad_arguments_exit_2(capsys) -> None:
    assert jp.main(["--jobs", "0"]) == 2
    assert "--jobs" in capsys.readouterr().err
    assert jp.main(["--judge-dir", str(ROOT)]) == 2
    assert "--judge-dir" in capsys.readouterr().err


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_the_seed_reaches_both_plans_and_the_settings_id() -> None:
    default = jp.build_units(jp.parse_args(["--judge-dir", str(JUDGE), "--tasks", "s00:b5"]), ["pybullet"])
    seeded = jp.build_units(jp.parse_args(["--judge-dir", str(JUDGE), "--tasks", "s00:b5", "--seed", "3"]),
                            ["pybullet"])
    assert default[0][0]["settings"]["seed"] == 0 and seeded[0][0]["settings"]["seed"] == 3
    assert default[1] != seeded[1]      # rows of another seed are never resumed as this one's


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_one_task_perceived_planned_and_judged(tmp_path: Path) -> None:
    pytest.importorskip("mujoco")
    out = tmp_path / "rows.jsonl"
    assert jp.main(["--judge-dir", str(JUDGE), "--tasks", "s00:b5", "--engine", "both", "--out", str(out)]) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert len(rows) == 1
    r = rows[0]
    assert r["key"] == "perceived|s00:b5" and r["scene"] == "s00" and r["target"] == "b5"
    assert r["boxes_true"] == 8 and 1 <= r["boxes_perceived"] and r["target_perceived"]
    assert set(r["perceived_to_true"].values()) <= {f"b{i}" for i in range(8)}
    a, b = r["a"], r["b"]
    assert a["sequence"][-1] == "b5" and b["sequence"][-1] == "b5"        # B's ids are the true ones
    assert r["perceived_to_true"][b["perceived_target"]] == "b5"
    assert len(b["perceived_sequence"]) == len(b["sequence"]) and b["unmapped_steps"] == []
    for plan in (a, b):
        assert set(plan["judges"]) == {"pybullet", "mujoco"}
        assert len(plan["judges"]["pybullet"]["step_collapse"]) == len(plan["sequence"])
        assert plan["plan_s"] > 0
    text = out.with_suffix(".md").read_text()
    assert "target perceived: 1/1" in text and "| pybullet |" in text and "| mujoco |" in text
    # resumed: nothing left to run, the same row
    assert jp.main(["--judge-dir", str(JUDGE), "--tasks", "s00:b5", "--engine", "both", "--out", str(out),
                    "--resume"]) == 0
    assert [json.loads(line)["key"] for line in out.read_text().splitlines()] == ["perceived|s00:b5"]
