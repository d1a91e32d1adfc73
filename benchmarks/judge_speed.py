"""Planning speed on the independent judge's shelves: make_plan wall and CPU time, p50 / p90.

The judge's 10-14 box extraction tasks (``../shared/judge/tasks.json``), observed as its camera
model gives them (``observe.py``, imported at run time, never copied), planned one after the other in
this process the way ``shelfpick plan`` plans (its defaults), and timed: wall time (what an operator
waits for; inflated on a loaded machine) and CPU time of this process and its workers.

    .venv/bin/python benchmarks/judge_speed.py --judge-dir ../shared/judge --workers 2 --noise 0
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from shelfpick.planning.bench_report import percentile  # noqa: E402


def _cpu() -> float:
    """CPU seconds of this process and its finished children (a pool keeps its workers alive: with
    --workers > 1 their CPU is not counted, read the wall time)."""
    me = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return me.ru_utime + me.ru_stime + kids.ru_utime + kids.ru_stime


def _fingerprint(task: dict, plan: dict) -> dict:
    """What a plan decides, without what depends on the machine (its timing)."""
    return {"task": f"{task['scene']}:{task['target']}", "plan": {k: v for k, v in plan.items() if k != "timing"}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--judge-dir", default=str(Path(__file__).resolve().parents[2] / "shared" / "judge"))
    ap.add_argument("--noise", type=float, default=0.0, help="perception error of observe.py, m (default 0)")
    ap.add_argument("--workers", type=int, default=1, help="make_plan workers (default 1)")
    ap.add_argument("--samples", type=int, default=10)
    ap.add_argument("--verify", type=int, default=10, help="make_plan verify: extra worlds a safe plan is asked of "
                                                          "(default 10, as shelfpick plan; 0: off)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N tasks")
    ap.add_argument("--min-boxes", type=int, default=10)
    ap.add_argument("--max-boxes", type=int, default=14)
    ap.add_argument("--dump", default=None,
                    help="write each plan (sequence, safety, risks; no timings) as a JSON line: diff two "
                         "runs to show a refactoring left the plans unchanged")
    args = ap.parse_args(argv)
    sys.path.insert(0, args.judge_dir)
    from observe import observed  # the judge's camera model, run from its own folder

    from shelfpick.perception.scene import Scene
    from shelfpick.planning.bullet_clients import ClientPool
    from shelfpick.planning.planner import make_plan
    from shelfpick.planning.worker_pool import WorkerPool

    tasks = [t for t in json.load(open(os.path.join(args.judge_dir, "tasks.json")))
             if args.min_boxes <= t["n_boxes"] <= args.max_boxes][: args.limit]
    walls, cpus = [], []
    dump = open(args.dump, "w") if args.dump else None
    # what a long-running planner (the console) keeps between plans: Bullet clients and workers
    clients = ClientPool()
    pool = WorkerPool(args.workers) if args.workers > 1 else None
    for t in tasks:
        truth = json.load(open(os.path.join(args.judge_dir, "scenes", t["scene"] + ".json")))
        scene = Scene.from_json(observed(truth, noise=args.noise, seed=int(t["scene"][1:]) + 17), t["scene"])
        c0, w0 = _cpu(), time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            plan = make_plan(scene, "extract", t["target"], samples=args.samples, workers=args.workers,
                             pool=pool, clients=clients, verify=args.verify)
        walls.append(time.perf_counter() - w0)
        if dump:
            dump.write(json.dumps(_fingerprint(t, plan.to_json()), sort_keys=True) + "\n")
        cpus.append(_cpu() - c0)
        print(f"{t['scene']}:{t['target']} {len(scene.boxes)} boxes  wall {walls[-1]:.2f} s  cpu {cpus[-1]:.2f} s  "
              f"pulls {plan.extra['search'].get('pulls', 0)}  steps {len(plan.sequence)}  "
              f"verify {plan.timing.get('verify_s', 0.0):.2f} s", flush=True)
    clients.close()
    if pool is not None:
        pool.close()
    print(f"{len(tasks)} tasks of {args.min_boxes}-{args.max_boxes} boxes, workers {args.workers}, noise {args.noise}, "
          f"verify {args.verify}: "
          f"wall p50 {percentile(walls, 0.5):.2f} s p90 {percentile(walls, 0.9):.2f} s; "
          f"cpu p50 {percentile(cpus, 0.5):.2f} s p90 {percentile(cpus, 0.9):.2f} s; load {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
