"""How often does the highest-first baseline collapse on the generated shelves?

For each stack kind: `--count` shelves (planning.shelves.generate), every box the target once;
the baseline's sequence (highest top first, up to the target) is executed on the shelf taken
as the truth: under the bench's perturbed truth (planning.bench.TruthModel: true masses,
friction, a pull without lift; the same draw `shelfpick bench` makes) and under the planner's
own physics (`nominal`). No planning, so it is quick: it measures the stacks, not the planner.

    .venv/bin/python benchmarks/highest_first.py --count 10 --seed 0 --out hf.json [--kinds proud,lean]
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def kind_rates(kind: str, count: int, seed: int, boxes: tuple[int, int] | None) -> dict:
    """Highest-first failure counts on one kind, under the perturbed truth and the nominal physics."""
    import numpy as np

    from shelfpick.perception.errors import SceneError
    from shelfpick.planning.bench import BenchConfig, derive_seed, true_world
    from shelfpick.planning.cmd_scenes import scene_seed
    from shelfpick.planning.execute import execute_plan
    from shelfpick.planning.heuristic import heuristic_order
    from shelfpick.planning.shelves import generate

    model = BenchConfig().truth
    out = {"kind": kind, "scenes": 0, "no_truth": 0, "tasks": 0, "fail_truth": 0, "fail_nominal": 0}
    for i in range(count):
        s = scene_seed(seed, i)
        n = None if boxes is None else int(np.random.default_rng([s & 0xFFFFFFFF, 7]).integers(boxes[0], boxes[1] + 1))
        scene = generate(kind, s, n)
        name = f"{kind}-{seed}-{i:04d}"
        out["scenes"] += 1
        try:
            truth, physics, _ = true_world(scene, model, derive_seed(0, name, "truth"))
        except SceneError:
            out["no_truth"] += 1
            continue
        for target in scene.ids:
            seq = heuristic_order(scene, target)
            run_seed = derive_seed(0, name, target)
            out["tasks"] += 1
            out["fail_truth"] += not execute_plan(truth, seq, seed=run_seed, config=physics).ok
            out["fail_nominal"] += not execute_plan(scene, seq, seed=run_seed).ok
    return out


def main(argv: list[str] | None = None) -> int:
    from shelfpick.planning.shelves import KINDS

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--kinds", default=",".join(KINDS), help=f"comma list of {', '.join(KINDS)}")
    ap.add_argument("--count", type=int, default=10, help="shelves per kind (default 10)")
    ap.add_argument("--seed", type=int, default=0, help="base seed, as `shelfpick scenes --seed` (default 0)")
    ap.add_argument("--boxes", default="8-14", help="boxes per shelf MIN-MAX (default 8-14)")
    ap.add_argument("--out", default=None, help="write the rows as JSON here")
    a = ap.parse_args(argv)
    kinds = [k.strip() for k in a.kinds.split(",") if k.strip()]
    bad = [k for k in kinds if k not in KINDS]
    if bad or a.count < 1:
        print(f"highest_first: --kinds: unknown kind {bad[0]!r}" if bad else
              f"highest_first: --count: expected a positive number, got {a.count}", file=sys.stderr)
        return 2
    from shelfpick.planning.cmd_scenes import parse_range
    boxes = parse_range(a.boxes)
    rows = []
    print("| kind | shelves | no truth | tasks | highest-first fails (perturbed truth) | (nominal physics) | s |")
    print("|---|---:|---:|---:|---:|---:|---:|")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for k in kinds:
            t0 = time.perf_counter()
            r = kind_rates(k, a.count, a.seed, boxes)
            r["wall_s"] = round(time.perf_counter() - t0, 1)
            rows.append(r)
            n = max(1, r["tasks"])
            print(f"| {k} | {r['scenes']} | {r['no_truth']} | {r['tasks']} | {r['fail_truth']} "
                  f"({100 * r['fail_truth'] / n:.0f}%) | {r['fail_nominal']} ({100 * r['fail_nominal'] / n:.0f}%) "
                  f"| {r['wall_s']} |", flush=True)
    if a.out:
        Path(a.out).write_text(json.dumps(rows, indent=1) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
