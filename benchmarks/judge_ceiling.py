"""Which of the judge's tasks can any plan hold? A search with the judge itself as the oracle.

A diagnostic of the target, not a planner: for each task it judges, on the TRUE shelf with the
independent judge's pybullet engine (../shared/judge, imported at run time, never copied), the
plans "remove these k boxes top first, then the target" for k = 0, 1, ... --max-remove over the
--candidates boxes nearest the target that are not wholly below it, and stops at the first plan
that holds. A plan found proves the task solvable; none found says only that no plan of that
shape holds. The count of tasks proven solvable bounds what any planner can reach from above only
where the search is exhaustive (the judge's own `min_removals` tasks); elsewhere it is a floor on
the ceiling, reported beside the tasks that no plan of ours ever held.

    .venv/bin/python benchmarks/judge_ceiling.py --tasks s03:b0,u06:b2 --out ceiling.jsonl

`--mode sets` searches wider: every box not wholly below the target, in any order that holds.
Breadth first over removal sets, smallest first: a set is reached by the first collapse-free
order found (each known order extended by one more box), and every set reached is tried with the
target pulled next. It stops at the first plan that holds, or when `--budget-s` runs out; the row's
`reached` says how many sets of each size were reached, one entry per size searched to the end.
`--engines pybullet,mujoco` asks every step to hold in both of the judge's engines: a plan
that holds in one engine only is marginal (issue 9), so this is the ceiling of robust plans.
"""
from __future__ import annotations

import argparse
import itertools
import json
import sys
import time
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import UsageError, init_worker, iter_rows, judge_fn, load_tasks  # noqa: E402


def candidates(scene: dict, target: str, n: int) -> list[str]:
    """The `n` boxes nearest the target (centre distance) whose top is above its bottom."""
    boxes = {b["id"]: b for b in scene["boxes"]}
    t = boxes[target]
    bottom = t["position"][2] - t["size"][2] / 2

    def dist(b: dict) -> float:
        return sum((p - q) ** 2 for p, q in zip(b["position"], t["position"])) ** 0.5
    above = [b for b in scene["boxes"] if b["id"] != target and b["position"][2] + b["size"][2] / 2 > bottom + 0.01]
    return [b["id"] for b in sorted(above, key=dist)[:n]]


def plans(scene: dict, target: str, n: int, k_max: int) -> list[list[str]]:
    """Every removal set up to `k_max` of the candidates, top first, then the target; smallest first."""
    z = {b["id"]: b["position"][2] for b in scene["boxes"]}
    cand = candidates(scene, target, n)
    out = []
    for k in range(k_max + 1):
        for subset in itertools.combinations(cand, k):
            out.append(sorted(subset, key=lambda i: -z[i]) + [target])
    return out


def _plan(target: str, sequence: list[str]) -> dict:
    return {"format": "shelfpick.plan/1", "task": "extract", "target": target, "sequence": sequence}


def _truth(unit: dict) -> dict:
    """The task's true shelf, the judge made importable in this process first."""
    init_worker(unit["judge_dir"])
    return json.loads((Path(unit["judge_dir"]) / "scenes" / f"{unit['task']['scene']}.json").read_text(encoding="utf-8"))


def search_task(unit: dict) -> dict:
    """Judge the task's plans in order until one holds."""
    scene, task = _truth(unit), unit["task"]
    t0 = time.perf_counter()
    tried, found = 0, None
    for seq in plans(scene, task["target"], unit["candidates"], unit["max_remove"]):
        tried += 1
        if judge_fn("pybullet")(scene, _plan(task["target"], seq), stop_on_collapse=True)["ok"]:
            found = seq
            break
    return {"task": f"{task['scene']}:{task['target']}", "found": found, "tried": tried,
            "s": round(time.perf_counter() - t0, 1)}


def _pull_then_target(scene: dict, path: list[str], box: str, target: str, engines: Sequence[str]) -> str:
    """Judge `path`, `box`, `target` (the path known to hold) with every engine: "ok" (held in all),
    "box" (pulling `box` collapses or sticks in one of them: this order is dead) or "target" (the
    path and box hold everywhere, the target does not yet)."""
    held = True
    for engine in engines:
        v = judge_fn(engine)(scene, _plan(target, [*path, box, target]), stop_on_collapse=True)
        step = v["steps"][len(path)] if len(v["steps"]) > len(path) else None
        if step is None or step.get("collapse") or not step.get("removed"):
            return "box"
        held = held and bool(v["ok"])
    return "ok" if held else "target"


def _extensions(frontier: list[list[str]], cands: list[str], seen: set[frozenset[str]]):
    """(order, box) for every known order and every box that makes a removal set not yet reached."""
    for path in frontier:
        for box in cands:
            if box not in path and frozenset(path) | {box} not in seen:
                yield path, box


def search_sets(unit: dict) -> dict:
    """Breadth first over collapse-free removal sets (module docstring, `--mode sets`). The row's
    `reached` counts the sets reached of each size searched to the end (size 0: the empty set)."""
    scene, task, engines = _truth(unit), unit["task"], unit["engines"]
    target, t0 = task["target"], time.perf_counter()
    cands = candidates(scene, target, len(scene["boxes"]))
    row = {"task": f"{task['scene']}:{target}", "found": None, "tried": 1, "reached": [1], "candidates": len(cands)}
    if all(judge_fn(e)(scene, _plan(target, [target]), stop_on_collapse=True)["ok"] for e in engines):
        return {**row, "found": [target], "s": round(time.perf_counter() - t0, 1)}
    frontier, seen = [[]], {frozenset()}
    while frontier:
        nxt = []
        for path, box in _extensions(frontier, cands, seen):
            if time.perf_counter() - t0 > unit["budget_s"]:
                return {**row, "s": round(time.perf_counter() - t0, 1)}
            row["tried"] += 1
            what = _pull_then_target(scene, path, box, target, engines)
            if what == "ok":
                return {**row, "found": [*path, box, target], "s": round(time.perf_counter() - t0, 1)}
            if what == "target":
                seen.add(frozenset(path) | {box})
                nxt.append([*path, box])
        row["reached"].append(len(nxt))
        frontier = nxt
    return {**row, "s": round(time.perf_counter() - t0, 1)}


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--tasks", default="all", help="as judge_report.py --tasks")
    ap.add_argument("--candidates", type=int, default=7, help="boxes nearest the target to remove from")
    ap.add_argument("--max-remove", type=int, default=3, help="largest removal set tried")
    ap.add_argument("--mode", choices=("top-first", "sets"), default="top-first",
                    help="top-first: the nearest candidates' subsets, top first; sets: breadth first over "
                         "every collapse-free removal set (see the module docstring)")
    ap.add_argument("--budget-s", type=float, default=600.0, help="--mode sets: seconds per task")
    ap.add_argument("--engines", default="pybullet",
                    help="--mode sets: comma list of the judge's engines (pybullet, mujoco) a plan must hold in, "
                         "every step of it")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default=None, help="rows (JSONL)")
    return ap.parse_args(argv)


def main(argv: Sequence[str] | None = None) -> int:
    a = parse_args(argv)
    try:
        if a.candidates < 0 or a.max_remove < 0 or a.jobs < 1:
            raise UsageError(f"--candidates, --max-remove, --jobs: expected counts, got "
                             f"{a.candidates}, {a.max_remove}, {a.jobs}")
        engines = [e.strip() for e in a.engines.split(",") if e.strip()]
        if not engines or set(engines) - {"pybullet", "mujoco"}:
            raise UsageError(f"--engines: expected pybullet and/or mujoco, got {a.engines!r}")
        if not a.budget_s > 0:
            raise UsageError(f"--budget-s: expected a positive number of seconds, got {a.budget_s}")
        judge_dir = str(Path(a.judge_dir).resolve())
        if not (Path(judge_dir) / "judge.py").is_file():
            raise UsageError(f"--judge-dir: {judge_dir} has no judge.py (the independent judge's folder)")
        tasks = load_tasks(Path(judge_dir), a.tasks, None)
    except UsageError as exc:
        print(f"judge_ceiling: {exc}", file=sys.stderr)
        return 2
    units = [{"task": t, "judge_dir": judge_dir, "candidates": a.candidates, "max_remove": a.max_remove,
              "budget_s": a.budget_s, "engines": engines} for t in tasks]
    rows = []
    out = open(a.out, "w", encoding="utf-8") if a.out else None
    try:
        for i, row in enumerate(iter_rows(units, a.jobs, search_sets if a.mode == "sets" else search_task), 1):
            rows.append(row)
            print(f"[{i}/{len(units)}] {row['task']}: {'holds: ' + ' '.join(row['found']) if row['found'] else 'none'}"
                  f" ({row['tried']} plans, {row['s']} s)", file=sys.stderr, flush=True)
            if out:
                out.write(json.dumps(row) + "\n")
                out.flush()
    finally:
        if out:
            out.close()
    found = sum(r["found"] is not None for r in rows)
    if a.mode == "sets":
        print(f"judge_ceiling: a collapse-free order found on {found} of {len(rows)} tasks (breadth first over "
              f"removal sets, {a.budget_s:g} s a task, holding in {' and '.join(engines)})")
        return 0
    print(f"judge_ceiling: a plan of {a.max_remove} removals or fewer among the {a.candidates} nearest boxes "
          f"holds on {found} of {len(rows)} tasks")
    return 0


if __name__ == "__main__":
    sys.exit(main())
