"""make_plan's wall time on 10-14 box shelves with the gate (issue 32), and what its adaptive worlds save.

    .venv/bin/python benchmarks/gate_speed.py [--scenes 6] [--targets 3] [--workers 2] [--out gate-speed]

The shelves and targets are `benchmarks/plan_speed.py`'s group extract-10-14 (structured and
unstructured, seed 0), planned with depths hidden as `shelfpick plan` plans them (10 worlds, the
cell's default threshold and map, up to 30 more worlds). Each plan is made twice on one pool of
`--workers` processes: with the gate as shipped (10 worlds, then 10 more while the calibrated
interval straddles the threshold), and with a gate that never decides early (always the 40 worlds).
Per mode: wall p50/p90 and the worlds the gate asked; the machine's load average with the table;
and two figures the load does not change: the physics pulls run (search and gate) and the CPU
seconds of this process and the pool's workers (read from /proc). `rows.jsonl` holds every plan's
sequence, verdict, failed-world count, risk and step predictions, so two runs can be diffed
(`--modes adaptive`: the shipped gate only, half the time). With `--workers 1` the plans share one
`ClientPool` (Bullet clients reused from plan to plan, as a pool worker's are).

`--against REV`: an A/B of `planning/predict.py` on a loaded machine. Each plan is made with the
shipped gate twice on the one pool, once with the Predictor of git revision REV (the rest of the
code is this tree's) and once with this tree's, the two taking turns to go first; the table then
compares the two under the same load, and says how many plans came out the same.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
import types
import warnings
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.plan_speed import _cpu, build_work, true_scene  # noqa: E402
from shelfpick.planning.bench_report import percentile  # noqa: E402
from shelfpick.planning.calibration import Calibration, calibration_for  # noqa: E402
from shelfpick.planning.uncertainty import Uncertainty  # noqa: E402


@dataclass(frozen=True)
class Undecided(Calibration):
    """The shipped map, but never decided before the last world: the gate asks all it may."""

    def decided(self, k: int, n: int, threshold: float, stands: bool = True) -> bool:
        return False


def predictor_at(rev: str) -> type:
    """The Predictor class of `planning/predict.py` at git revision `rev` (imported beside this tree's)."""
    src = subprocess.run(["git", "-C", str(ROOT), "show", f"{rev}:planning/predict.py"],
                         capture_output=True, text=True, check=True).stdout
    mod = types.ModuleType(f"predict_at_{rev}")
    mod.__file__ = f"{rev}:planning/predict.py"
    sys.modules[mod.__name__] = mod
    exec(compile(src, mod.__file__, "exec"), mod.__dict__)
    return mod.Predictor


def main(argv: list[str] | None = None) -> int:
    import numpy as np

    from shelfpick.planning.bullet_clients import ClientPool
    from shelfpick.planning.planner import make_plan
    from shelfpick.planning.predict import Predictor
    from shelfpick.planning.worker_pool import WorkerPool

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", type=int, default=6, help="scenes per kind (default 6)")
    ap.add_argument("--targets", type=int, default=3)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="gate-speed")
    ap.add_argument("--modes", choices=("both", "adaptive"), default="both",
                    help="both gates (default), or the shipped adaptive one only")
    ap.add_argument("--against", metavar="REV", default=None,
                    help="A/B: the shipped gate with REV's planning/predict.py and with this tree's")
    ap.add_argument("--method", choices=("forkserver", "spawn"), default=None,
                    help="how the pool starts its workers (default forkserver where there is one)")
    a = ap.parse_args(argv)
    out = Path(a.out)
    (out / "scenes").mkdir(parents=True, exist_ok=True)
    shipped = calibration_for(Uncertainty().pull_modes)
    modes = {"adaptive (shipped)": (shipped, Predictor),
             "always 40 worlds": (Undecided(**shipped.to_json()), Predictor)}
    if a.modes == "adaptive":
        modes = {"adaptive (shipped)": (shipped, Predictor)}
    if a.against:
        modes = {f"adaptive, predict.py at {a.against}": (shipped, predictor_at(a.against)),
                 "adaptive, this tree": (shipped, Predictor)}
    args = argparse.Namespace(groups="extract-10-14", scenes=a.scenes, seed=a.seed)
    rows = []
    load0 = os.getloadavg()
    pool = WorkerPool(a.workers, method=a.method) if a.workers > 1 else None
    if pool is not None:   # started before the first plan (as the console's are): no plan pays for it
        pool.give_back(pool.lease(a.workers))
    clients = ClientPool() if pool is None else None   # one process: its clients serve every plan
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            for g, task, kind, s, n in build_work(args):
                truth = true_scene(out / "scenes" / f"{g}-{kind}-{s}.json", kind, s, n)
                hidden = truth.hide_depths()
                rng = np.random.default_rng([s, 1])
                for i in rng.choice(len(truth.ids), min(a.targets, len(truth.ids)), replace=False):
                    turn = list(modes.items())
                    if a.against and (len(rows) // 2) % 2:
                        turn.reverse()      # A/B: each side goes first every other plan
                    for name, (cal, make) in turn:
                        t0, c0 = time.perf_counter(), _cpu(pool)
                        # the Predictor make_plan would build (same samples, seed, workers, pool),
                        # built here so that its pull count can be read
                        pred = make(hidden, 10, s, workers=a.workers, pool=pool, clients=clients)
                        try:
                            plan = make_plan(hidden, "extract", truth.ids[int(i)], "physics", 10, s,
                                             workers=a.workers, pool=pool, calibration=cal, predictor=pred)
                        finally:
                            pred.close()
                        wall, cpu = time.perf_counter() - t0, _cpu(pool) - c0
                        search = plan.extra.get("search", {})
                        rows.append({"mode": name, "kind": kind, "seed": s, "n_boxes": n, "target": truth.ids[int(i)],
                                     "plan_s": wall, "cpu_s": cpu, "worlds": search.get("verified_worlds"),
                                     "safe": plan.safe, "sequence": list(plan.sequence),
                                     "failed_worlds": search.get("plan_risk", {}).get("failed_worlds"),
                                     "plan_risk": search.get("plan_risk"),
                                     "predicted": [[x.box, x.collapse_prob, x.collision_prob, list(x.moved)]
                                                   for x in plan.predicted],
                                     "pulls": pred.stats["pulls"], "search_pulls": search.get("pulls"),
                                     "oracle_calls": search.get("oracle_calls")})
                        print(json.dumps(rows[-1]), flush=True)
    finally:
        if pool is not None:
            pool.close()
        if clients is not None:
            clients.close()
    load1 = os.getloadavg()
    lines = [f"make_plan, extract on 10-14 box shelves, {a.workers} workers, {len(rows) // len(modes)} plans; "
             f"load average (1/5/15 min) {'/'.join(f'{x:.1f}' for x in load0)} at the start, "
             f"{'/'.join(f'{x:.1f}' for x in load1)} at the end", "",
             "| gate | p50 wall (s) | p90 wall (s) | mean worlds asked | plans decided on 10 worlds | safe "
             "| pulls (all plans) | CPU s (all plans, main + workers) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for name in modes:
        r = [x for x in rows if x["mode"] == name]
        t = [x["plan_s"] for x in r]
        w = [x["worlds"] or 0 for x in r]
        lines.append(f"| {name} | {percentile(t, 0.5):.2f} | {percentile(t, 0.9):.2f} | {sum(w) / len(w):.1f} | "
                     f"{sum(1 for x in w if x <= 10)}/{len(w)} | {sum(x['safe'] for x in r)}/{len(r)} | "
                     f"{sum(x['pulls'] for x in r)} | {sum(x['cpu_s'] for x in r):.1f} |")
    if a.against:
        key = ("kind", "seed", "target", "sequence", "safe", "failed_worlds", "worlds")
        sides = [[tuple(json.dumps(x[k]) for k in key) for x in rows if x["mode"] == name] for name in modes]
        lines += ["", f"plans with the same sequence, verdict and failed worlds on both sides: "
                      f"{sum(p == q for p, q in zip(*sides))}/{len(sides[0])}"]
    text = "\n".join(lines) + "\n"
    (out / "rows.jsonl").write_text("".join(json.dumps(x) + "\n" for x in rows))
    (out / "gate_speed.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
