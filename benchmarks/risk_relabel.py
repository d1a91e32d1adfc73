"""Judge the plans of `risk_calibration.py collect` rows again on the truth of the code that runs this.

    .venv/bin/python benchmarks/risk_relabel.py ROWS.jsonl OUT.jsonl

The sample worlds' verdicts in the rows are kept; the truth (the same shelf, truth draw and
observation seeds as `collect`) is rebuilt and every step executed again, so two collections made
with different physics of the worlds can be compared against one truth (issue 32: a change to the
pull changes the truth as well as the worlds). Rows whose truth cannot be rebuilt are dropped.
"""
from __future__ import annotations

import json
import sys
import warnings
from collections import defaultdict
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.risk_calibration import _truth_model, _truth_step  # noqa: E402


def relabel_view(rows: list[dict], base_seed: int) -> list[dict]:
    """The rows of one shelf view with the truth's verdicts made again."""
    from shelfpick.perception.errors import SceneError
    from shelfpick.planning.bench import derive_seed, true_world
    from shelfpick.planning.execute import execute_plan
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.shelves import generate

    r0 = rows[0]
    name, kind, noise, pull = r0["scene"], r0["kind"], r0["noise"], r0.get("truth_pull", "drag")
    scene = generate(kind, int(name.rsplit("-", 1)[1]), None)
    try:
        truth, physics, _ = true_world(scene, _truth_model(pull, noise, derive_seed(base_seed, name, "lift")),
                                       derive_seed(base_seed, name, "truth"))
    except SceneError:
        return []
    cfg = PhysicsConfig()
    out = []
    plans: dict[str, list[dict]] = defaultdict(list)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for r in rows:
            if r["source"] == "alone":
                ex = execute_plan(truth, [r["box"]], seed=derive_seed(base_seed, name, "alone", r["box"]), config=physics)
                out.append(dict(r, **_truth_step(ex.steps[0], cfg)))
            else:
                plans[r["target"]].append(r)
        for target, steps in plans.items():
            steps.sort(key=lambda r: r["step"])
            ex = execute_plan(truth, [r["box"] for r in steps], seed=derive_seed(base_seed, name, target), config=physics)
            for r, st in zip(steps, ex.steps):
                out.append(dict(r, plan_ok=bool(ex.ok), **_truth_step(st, cfg)))
    return out


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    src, dst = args[0], args[1]
    base_seed = int(args[2]) if len(args) > 2 else 11
    views: dict[tuple, list[dict]] = defaultdict(list)
    for line in Path(src).read_text().splitlines():
        if line.strip():
            r = json.loads(line)
            views[(r["scene"], r["noise"])].append(r)
    with open(dst, "w") as fh:
        for key, rows in views.items():
            fh.write("".join(json.dumps(r) + "\n" for r in relabel_view(rows, base_seed)))
            print(key, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
