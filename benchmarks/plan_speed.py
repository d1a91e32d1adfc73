"""Issue 5's planning-speed benchmark: make_plan time (p50/p90) and plan quality on the true scene.

Groups: extraction on 10-14 box scenes, extraction on 25-30 box scenes, clearance on
10-14 box scenes; structured and unstructured shelves from the generator; 10 depth
samples, risk 0; plans made with depths hidden and executed on the true scene.
Timing is make_plan's wall time including building the Predictor (what an operator waits for),
and its CPU time (on a shared, loaded machine wall time is inflated; CPU time is what an
idle machine would show for a single-process plan).

    .venv/bin/python benchmarks/plan_speed.py --scenes 6 --targets 3 --out bench-speed
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from shelfpick.planning.bench import derive_seed  # noqa: E402
from shelfpick.planning.bench_report import percentile  # noqa: E402


def _cpu(pool=None) -> float:
    """CPU seconds of this process, its waited-for children and the live pool workers.

    The pool's processes outlive each Predictor (the pool keeps them for the
    next one), so their CPU time is read from /proc while they live.
    """
    import os
    import resource

    own = time.process_time()
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    tick = os.sysconf("SC_CLK_TCK")
    workers = 0.0
    for pid in (pool.pids() if pool is not None else []):
        try:
            with open(f"/proc/{pid}/stat") as fh:
                f = fh.read().rsplit(")", 1)[1].split()
            workers += (int(f[11]) + int(f[12])) / tick   # utime, stime
        except (OSError, IndexError, ValueError):
            pass
    return own + ch.ru_utime + ch.ru_stime + workers


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=6, help="scenes per group and kind (default 6)")
    ap.add_argument("--targets", type=int, default=3, help="extraction targets per scene (default 3)")
    ap.add_argument("--samples", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--groups", default="extract-10-14,extract-25-30,clear-10-14")
    ap.add_argument("--out", default="bench-speed")
    ap.add_argument("--scene-dir", default=None,
                    help="true scenes are read from here when present, else generated and written "
                         "here (default OUT/scenes): before/after runs compare the same shelves")
    ap.add_argument("--workers", type=int, default=1,
                    help="processes per Predictor over the depth samples (default 1)")
    ap.add_argument("--physics", default=None, metavar="JSON",
                    help='PhysicsConfig overrides, to measure a lever on and off, '
                         'e.g. \'{"prediction_local": false}\'')
    return ap.parse_args(argv)


def build_work(args: argparse.Namespace) -> list[tuple[str, str, str, int, int]]:
    """(group, task, kind, seed, box count) for every scene of every group and kind."""
    import numpy as np

    work = []
    for g in args.groups.split(","):
        task, lo, hi = g.split("-")[0], int(g.split("-")[1]), int(g.split("-")[2])
        for kind in ("structured", "unstructured"):
            for i in range(args.scenes):
                s = derive_seed(args.seed, g, kind, i)
                n = int(np.random.default_rng(s).integers(lo, hi + 1))
                work.append((g, task, kind, s, n))
    return work


def true_scene(cached: Path, kind: str, seed: int, n: int):
    """The true scene from the scene folder, or generated and written there (the same shelves next run)."""
    from shelfpick.perception.scene import Scene
    from shelfpick.planning.shelves import generate

    if cached.exists():
        return Scene.load(cached)
    truth = generate(kind, seed, n)
    truth.save(cached)
    return truth


def timed_plan(hidden, task: str, target: str | None, seed: int, args: argparse.Namespace, config, pool,
               clients=None):
    """make_plan, with its own Predictor on the pool when there are workers (else on `clients`, the
    run's Bullet clients); (plan, wall s, CPU s)."""
    from shelfpick.planning.planner import make_plan
    from shelfpick.planning.predict import Predictor

    t0 = time.perf_counter()
    c0 = _cpu(pool)
    pred = (Predictor(hidden, args.samples, seed, config, workers=args.workers, pool=pool)
            if args.workers > 1 else None)
    try:
        plan = make_plan(hidden, task, target, "physics", args.samples, seed, risk=0.0, config=config,
                         predictor=pred, clients=clients)
    finally:
        if pred is not None:
            pred.close()
    return plan, time.perf_counter() - t0, _cpu(pool) - c0


def scene_rows(item: tuple[str, str, str, int, int], args: argparse.Namespace, config, pool,
               scene_dir: Path, out: Path, clients=None) -> list[dict]:
    """Every target of one scene planned (timed) on the hidden-depth scene and executed on the truth."""
    import numpy as np

    from shelfpick.planning.execute import execute_plan

    g, task, kind, s, n = item
    try:
        truth = true_scene(scene_dir / f"{g}-{kind}-{s}.json", kind, s, n)
    except Exception as exc:  # a seed the generator cannot fill: say so, go on
        return [{"group": g, "kind": kind, "seed": s, "error": str(exc)}]
    hidden = truth.hide_depths()
    rng = np.random.default_rng([s, 1])
    targets = ([None] if task == "clear" else
               [truth.ids[int(i)] for i in rng.choice(len(truth.ids), min(args.targets, len(truth.ids)), replace=False)])
    rows = []
    for t in targets:
        plan, dt, dc = timed_plan(hidden, task, t, s, args, config, pool, clients)
        ex = execute_plan(truth, plan.sequence, seed=s)   # the default physics: the truth
        row = {"group": g, "kind": kind, "seed": s, "n_boxes": n, "target": t,
               "plan_s": dt, "cpu_s": dc, "ok": bool(ex.ok), "removed": len(plan.sequence),
               "safe": plan.safe, "sequence": list(plan.sequence),
               "plan_risk": plan.extra.get("search", {}).get("plan_risk"),
               "predicted": [[x.box, x.collapse_prob, x.collision_prob, list(x.moved)] for x in plan.predicted],
               "oracle_calls": plan.extra.get("search", {}).get("oracle_calls")}
        rows.append(row)
        with open(out / "rows.jsonl", "a") as fh:   # what is done survives a stopped run
            fh.write(json.dumps(row) + "\n")
    return rows


def run_work(work: list, args: argparse.Namespace, config, out: Path, scene_dir: Path) -> list[dict]:
    """All scenes in turn (one worker pool for all of them when --workers > 1), with a progress bar."""
    from tqdm import tqdm

    from shelfpick.planning.bullet_clients import ClientPool
    from shelfpick.planning.worker_pool import WorkerPool

    pool = WorkerPool(args.workers) if args.workers > 1 else None
    clients = ClientPool() if pool is None else None   # one process: its clients serve every plan
    rows: list[dict] = []
    bar = tqdm(total=len(work), desc="plan speed", unit="scene")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for item in work:
            rows += scene_rows(item, args, config, pool, scene_dir, out, clients)
            bar.update()
    bar.close()
    if pool is not None:
        pool.close()
    if clients is not None:
        clients.close()
    return rows


def summarize(rows: list[dict], groups: list[str]) -> dict:
    """Per group: plan wall and CPU time percentiles, success on the true scene, boxes removed."""
    summary = {}
    for g in groups:
        r = [x for x in rows if x["group"] == g and "plan_s" in x]
        if not r:
            continue
        times = [x["plan_s"] for x in r]
        cpus = [x["cpu_s"] for x in r]
        summary[g] = {"plans": len(r), "p50_s": percentile(times, 0.5), "p90_s": percentile(times, 0.9),
                      "mean_s": statistics.fmean(times),
                      "cpu_p50_s": percentile(cpus, 0.5), "cpu_p90_s": percentile(cpus, 0.9),
                      "success_rate": sum(x["ok"] for x in r) / len(r),
                      "mean_removed": statistics.fmean(x["removed"] for x in r),
                      "skipped_scenes": sum(1 for x in rows if x["group"] == g and "error" in x)}
    return summary


def report(args: argparse.Namespace, summary: dict, load_start, load_end) -> str:
    """The markdown table, headed by the settings and the machine's load at the start and the end."""
    md = ["| group | plans | p50 wall (s) | p90 wall (s) | p50 CPU (s) | p90 CPU (s) "
          "| success on true scene | boxes removed |",
          "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for g, v in summary.items():
        md.append(f"| {g} | {v['plans']} | {v['p50_s']:.2f} | {v['p90_s']:.2f} | "
                  f"{v['cpu_p50_s']:.2f} | {v['cpu_p90_s']:.2f} | "
                  f"{v['success_rate'] * 100:.1f}% | {v['mean_removed']:.2f} |")
    return (f"Planning speed, {args.samples} depth samples, risk 0, seed {args.seed}, "
            f"{args.scenes} scenes per kind and group, {args.workers} worker(s); load average "
            f"(1/5/15 min) {'/'.join(f'{x:.1f}' for x in load_start)} at the start, "
            f"{'/'.join(f'{x:.1f}' for x in load_end)} at the end\n\n" + "\n".join(md) + "\n")


def main(argv: list[str] | None = None) -> int:
    """Plan every scene, write rows.jsonl, plan_speed.json and plan_speed.md under --out, print the table."""
    import os

    from shelfpick.planning.physics import PhysicsConfig

    args = parse_args(argv)
    config = PhysicsConfig.from_json(json.loads(args.physics), "--physics") if args.physics else None
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scene_dir = Path(args.scene_dir) if args.scene_dir else out / "scenes"
    scene_dir.mkdir(parents=True, exist_ok=True)
    work = build_work(args)
    load_start = os.getloadavg()
    rows = run_work(work, args, config, out, scene_dir)
    summary = summarize(rows, args.groups.split(","))
    load_end = os.getloadavg()
    doc = {"config": vars(args), "load_average": {"start": load_start, "end": load_end},
           "summary": summary, "rows": rows}
    (out / "plan_speed.json").write_text(json.dumps(doc, indent=2) + "\n")
    text = report(args, summary, load_start, load_end)
    (out / "plan_speed.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
