"""benchmarks/judge_compare.py: per-seed figures, the seed noise and the steady changes, on rows made in code."""
from __future__ import annotations

import json

from bench_scripts import load

jc = load("judge_compare")


def _row(task: str, ok: bool, safe: bool = False, noise: float = 0.0, mujoco: bool | None = None,
         planner: str = "physics") -> dict:
    """A judge_report row as far as the comparison reads it."""
    judges = {"pybullet": {"ok": ok}}
    if mujoco is not None:
        judges["mujoco"] = {"ok": mujoco}
    return {"key": f"{noise:g}|{planner}|{task}", "noise": noise, "planner": planner, "declared_safe": safe,
            "judges": judges, "scene": task, "target": "b0", "kind": "structured", "sequence": ["b0"],
            "exhaustive": False, "min_removals": None}


def _write(path, rows) -> str:
    path.write_text("".join(json.dumps(r) + "\n" for r in rows))
    return str(path)


def test_a_change_in_every_seed_is_told_from_the_draws(tmp_path, capsys):
    # t1 flips with the seed in both variants (draws); B holds t2 in every seed (a steady gain);
    # B declares t3 safe and it collapses
    a0 = _write(tmp_path / "a0", [_row("t1", True), _row("t2", False), _row("t3", True)])
    a1 = _write(tmp_path / "a1", [_row("t1", False), _row("t2", False), _row("t3", True)])
    b0 = _write(tmp_path / "b0", [_row("t1", False), _row("t2", True), _row("t3", False, safe=True)])
    b1 = _write(tmp_path / "b1", [_row("t1", True), _row("t2", True), _row("t3", True)])
    recs = jc.compare([jc.read(a0), jc.read(a1)], [jc.read(b0), jc.read(b1)])
    assert len(recs) == 1           # no MuJoCo verdicts in these rows
    r = recs[0]
    assert r["a"] == [(2, 3, 0, 0), (1, 3, 0, 0)] and r["b"] == [(1, 3, 1, 1), (3, 3, 0, 0)]
    assert r["a_mean"] == 1.5 and r["b_mean"] == 2.0
    assert r["a_seed_noise"] == 1.0 and r["b_seed_noise"] == 2.0
    assert r["gained"] == ["0|physics|t2"] and r["lost"] == []
    out = tmp_path / "cmp.md"
    assert jc.main(["--a", f"{a0},{a1}", "--b", f"{b0},{b1}", "--out", str(out)]) == 0
    assert "| 0 | physics | pybullet | 2/3 (0/0), 1/3 (0/0) | 1/3 (1/1), 3/3 (0/0) | 1.5 | 2.0 | +0.5 | 1.0 / 2.0 " \
           "| 0|physics|t2 | - |" in out.read_text()


def test_planners_and_noise_levels_are_compared_apart(tmp_path):
    rows = [_row("t1", True), _row("t1", False, planner="heuristic"), _row("t1", False, noise=0.01)]
    run = _write(tmp_path / "run", rows)
    recs = jc.compare([jc.read(run)], [jc.read(run)])
    assert [(r["noise"], r["planner"], r["a"]) for r in recs] == [
        (0.0, "heuristic", [(0, 1, 0, 0)]), (0.0, "physics", [(1, 1, 0, 0)]), (0.01, "physics", [(0, 1, 0, 0)])]


def test_only_the_tasks_every_file_holds_are_counted(tmp_path):
    full = _write(tmp_path / "full", [_row("t1", True, mujoco=False), _row("t2", True, mujoco=True)])
    part = _write(tmp_path / "part", [_row("t1", False, mujoco=False)])
    recs = jc.compare([jc.read(full)], [jc.read(part)])
    assert [(r["engine"], r["a"], r["b"]) for r in recs] == [("pybullet", [(1, 1, 0, 0)], [(0, 1, 0, 0)]),
                                                             ("mujoco", [(0, 1, 0, 0)], [(0, 1, 0, 0)])]
    assert recs[0]["a_seed_noise"] is None     # one seed: no seed noise to tell


def test_a_missing_or_empty_rows_file_exits_2_naming_it(tmp_path, capsys):
    good = _write(tmp_path / "good", [_row("t1", True)])
    assert jc.main(["--a", str(tmp_path / "nope.jsonl"), "--b", good]) == 2
    assert "nope.jsonl: no such rows file" in capsys.readouterr().err
    bad = tmp_path / "bad"
    bad.write_text('{"no key": 1}\nnot json\n')
    assert jc.main(["--a", good, "--b", str(bad)]) == 2
    assert "bad: no judge_report rows in it" in capsys.readouterr().err


def test_a_torn_last_line_of_a_run_still_going_is_left_out(tmp_path):
    path = tmp_path / "going"
    path.write_text(json.dumps(_row("t1", True)) + "\n" + json.dumps(_row("t2", True))[:30])
    assert list(jc.read(str(path))) == ["0|physics|t1"]
