"""`plan` and `simulate` against arguments and files that used to cost memory or trust (issue 30):
every bound is checked before anything is allocated, in one line naming the option or field."""
from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest

from shelfpick.console.cli import main

ROOT = Path(__file__).resolve().parents[2]
SCENE = {"format": "shelfpick.scene/1", "shelf": {"width": 1.0, "depth": 0.3, "height": 1.6},
         "boxes": [{"id": "a", "size": [0.2, 0.2, 0.2], "position": [-0.2, 0.12, 0.1]},
                   {"id": "b", "size": [0.2, 0.2, 0.2], "position": [0.2, 0.12, 0.1]}]}


def one_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "Traceback" not in err[0], err
    return err[0]


@pytest.fixture()
def scene(tmp_path: Path) -> Path:
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(SCENE))
    return p


@pytest.mark.parametrize("option, value, says", [
    ("--samples", "1000000000", "--samples: expected a positive integer from 1 to 1000, got 1000000000"),
    ("--verify", "1000000000", "--verify: expected a number of sample worlds from 0 to 1000"),
    ("--workers", "1000000", "--workers: expected a positive integer from 1 to 256"),
    ("--seed", "-1", "--seed: expected a seed from 0 to"),
    ("--budget", "1e308", "--budget: expected a positive number of seconds"),
])
def test_plan_options_are_bounded(scene: Path, capsys, option: str, value: str, says: str) -> None:
    assert main(["plan", str(scene), "--task", "clear", option, value]) == 2
    assert says in one_line(capsys)


def test_a_billion_samples_is_refused_in_a_small_memory(scene: Path) -> None:
    """A subprocess with its data segment limited to 2 GB: refused at once (the old code went on
    to build sample worlds until it was killed at 17.8 GB)."""
    def limit() -> None:
        resource.setrlimit(resource.RLIMIT_DATA, (2 << 30, 2 << 30))

    p = subprocess.run([sys.executable, "-m", "shelfpick.console.cli", "plan", str(scene), "--task", "clear",
                        "--samples", "1000000000"], cwd=ROOT, capture_output=True, text=True, timeout=60,
                       preexec_fn=limit)
    assert p.returncode == 2 and "--samples" in p.stderr and "Traceback" not in p.stderr


def test_simulate_refuses_a_plan_that_says_safe_with_risk_one(scene: Path, tmp_path: Path, capsys) -> None:
    plan = {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "physics",
            "sequence": ["a"], "safe": True, "predicted": [{"box": "a", "collapse_prob": 1.0}]}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    assert main(["simulate", str(scene), str(tmp_path / "plan.json")]) == 2
    line = one_line(capsys)
    assert "plan.json: safe: true, but step 1 ('a') has predicted risk 1" in line
    plan["provenance"] = {"risk": 1.0}          # planned with a threshold of 1: it is what was asked
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    from shelfpick.planning.plan import Plan

    assert Plan.load(tmp_path / "plan.json").safe


def test_simulate_refuses_a_fifo_out_before_simulating(scene: Path, tmp_path: Path, capsys) -> None:
    plan = {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "heuristic",
            "sequence": ["a"], "safe": True}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    os.mkfifo(tmp_path / "v.json")
    assert main(["simulate", str(scene), str(tmp_path / "plan.json"), "--out", str(tmp_path / "v.json")]) == 2
    assert "v.json: --out: a FIFO, not a regular file" in one_line(capsys)
