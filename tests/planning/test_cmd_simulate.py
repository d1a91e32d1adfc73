"""`shelfpick simulate SCENE PLAN`: JSON verdict on stdout, bad input -> one line, exit 2."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from shelfpick.console.cli import main
from shelfpick.planning.plan import Plan
from tests.planning.sim_scenes import stacked

ROOT = Path(__file__).resolve().parents[2]


def write(tmp_path: Path, sequence, name="plan.json") -> tuple[str, str]:
    scene = tmp_path / "scene.json"
    stacked().save(scene)
    plan = tmp_path / name
    Plan("extract", sequence[-1], "physics", tuple(sequence)).save(plan)
    return str(scene), str(plan)


def test_simulate_prints_a_parseable_verdict(tmp_path):
    scene, plan = write(tmp_path, ["b", "a"])
    proc = subprocess.run([sys.executable, "-m", "shelfpick.console.cli", "simulate", scene, plan, "--seed", "2"],
                          cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    doc = json.loads(proc.stdout)  # nothing but JSON on stdout (pybullet's banner is kept off it)
    assert doc["ok"] is True and doc["seed"] == 2 and doc["target"] == "a"
    assert [s["box"] for s in doc["steps"]] == ["b", "a"]
    assert all(s["collapse"] is False and s["collision"] is False for s in doc["steps"])


def test_simulate_reports_a_collapse(tmp_path, capsys):
    scene, plan = write(tmp_path, ["a"])
    out = tmp_path / "verdict.json"
    assert main(["simulate", scene, plan, "--out", str(out)]) == 3   # the plan did not hold (docs/cli.md)
    doc = json.loads(capsys.readouterr().out)
    assert doc["ok"] is False and doc["steps"][0]["collapsed"] == ["b"]
    assert json.loads(out.read_text())["ok"] is False


def test_unknown_box_in_the_plan_is_exit_2_naming_it(tmp_path, capsys):
    scene, plan = write(tmp_path, ["zz", "a"])
    assert main(["simulate", scene, plan]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "plan.json" in err and "sequence[0]" in err and "'zz'" in err


def test_malformed_files_are_exit_2(tmp_path, capsys):
    scene, plan = write(tmp_path, ["a"])
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["simulate", str(bad), plan]) == 2
    assert "bad.json" in capsys.readouterr().err
    assert main(["simulate", scene, str(tmp_path / "missing.json")]) == 2
    assert "missing.json" in capsys.readouterr().err
    overlapping = json.loads(Path(scene).read_text())
    overlapping["boxes"][1]["position"][2] = 0.22   # 8 cm into the box below
    Path(scene).write_text(json.dumps(overlapping))
    assert main(["simulate", scene, plan]) == 2
    err = capsys.readouterr().err
    assert "'a'" in err and "'b'" in err and "overlap" in err
