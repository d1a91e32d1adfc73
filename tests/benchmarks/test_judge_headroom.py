"""benchmarks/judge_headroom.py: every task sorted by what our plan did against what any plan can do."""
from __future__ import annotations

import json
from pathlib import Path

from bench_scripts import load

jh = load("judge_headroom")


def _eval_row(task: str, ok: bool, kind: str = "structured") -> str:
    scene, target = task.split(":")
    return json.dumps({"scene": scene, "target": target, "kind": kind, "ok": ok, "sequence": [target]})


def _write(path: Path, lines: list[str]) -> str:
    path.write_text("pybullet build time: today\n" + "\n".join(lines) + "\nphysics, noise 0.0 cm: ok 2/5\n")
    return str(path)


def test_tasks_are_sorted_and_counted(tmp_path: Path, capsys) -> None:
    tasks = {"s0:a": (True, True), "s0:b": (True, False), "s1:c": (True, False), "u0:d": (False, False),
             "u0:e": (False, False), "u1:f": (False, False), "u1:g": (False, False)}
    py = _write(tmp_path / "py.log", [_eval_row(t, p, "unstructured" if t[0] == "u" else "structured")
                                      for t, (p, _) in tasks.items()])
    mj = _write(tmp_path / "mj.log", [_eval_row(t, m) for t, (_, m) in tasks.items()])
    sets_py = _write(tmp_path / "sp.jsonl", [json.dumps({"task": t, "found": f}) for t, f in
                                             (("u0:d", ["x", "d"]), ("u0:e", ["e"]), ("u1:f", None))])
    sets_both = _write(tmp_path / "sb.jsonl", [json.dumps({"task": t, "found": f}) for t, f in
                                               (("s0:b", ["b"]), ("s1:c", None), ("u0:d", None), ("u0:e", ["e"]))])
    png = tmp_path / "h.png"
    assert jh.main(["--ours-pybullet", py, "--ours-mujoco", mj, "--sets-pybullet", sets_py,
                    "--sets-both", sets_both, "--png", str(png)]) == 0
    out = capsys.readouterr().out
    classes = jh.classify(jh.verdicts(py, "pybullet"), jh.verdicts(mj, "mujoco"), jh.found(sets_py), jh.found(sets_both))
    assert classes == {"s0:a": "ours, both engines", "s0:b": "ours, pybullet only, robust plan exists",
                       "s1:c": "ours, pybullet only", "u0:d": "missed, pybullet-only plan exists",
                       "u0:e": "missed, robust plan exists", "u1:f": "no plan holds", "u1:g": "not searched"}
    # held in pybullet: ours 3 + u0:d + u0:e; in both: s0:a, s0:b, u0:e
    assert "ours hold in pybullet 3/7; a plan holds in pybullet on 5, in both engines on 3; 1 not searched" in out
    assert png.stat().st_size > 5000


def test_judge_report_rows_carry_both_engines(tmp_path: Path) -> None:
    row = {"key": "0|physics|s0:a", "scene": "s0", "target": "a", "kind": "structured", "planner": "physics",
           "judges": {"pybullet": {"ok": True}, "mujoco": {"ok": False}}}
    other = dict(row, planner="heuristic", judges={"pybullet": {"ok": False}, "mujoco": {"ok": False}})
    path = _write(tmp_path / "r.jsonl", [json.dumps(row), json.dumps(other)])
    assert jh.verdicts(path, "pybullet") == {"s0:a": (True, "structured")}
    assert jh.verdicts(path, "mujoco") == {"s0:a": (False, "structured")}


def test_unreadable_rows_exit_2(tmp_path: Path, capsys) -> None:
    bad = tmp_path / "bad.log"
    bad.write_text('{"scene": "s0",\n')
    args = ["--ours-mujoco", str(bad), "--sets-pybullet", str(bad), "--sets-both", str(bad)]
    assert jh.main(["--ours-pybullet", str(tmp_path / "missing.log"), *args]) == 2
    assert "missing.log: cannot read" in capsys.readouterr().err
    assert jh.main(["--ours-pybullet", str(bad), *args]) == 2
    assert "bad.log: line 1 is not a JSON row" in capsys.readouterr().err
