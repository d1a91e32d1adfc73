"""Issue 5's throughput check: `shelfpick bench` serially, with local workers and on Ray (local).

Runs the real command line on one small fixed set of scenes in each mode, checks that the
records are identical apart from the machine's timings (same seeds, same numbers), and
reports throughput (target tasks and plans per second; a task = one target, planned by each
planner and executed on the true scene) and the scaling from 1 to N workers. Writes
`scaling.md` and `scaling.json` into --out.

    .venv/bin/python benchmarks/bench_scaling.py --out bench-scaling            # 2+2 scenes of 8-9 boxes
    .venv/bin/python benchmarks/bench_scaling.py --scenes /work/benchdata/structured --limit 3

Wall times include process start-up (and Ray's start for the Ray mode), as a user sees them.
On a shared machine the figures move with the load: the load average is recorded with them.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from shelfpick.planning.bench import comparable, read_records  # noqa: E402


def _shelfpick() -> list[str]:
    exe = Path(sys.executable).with_name("shelfpick")
    return [str(exe)] if exe.exists() else [sys.executable, "-m", "shelfpick.console.cli"]


def make_scenes(out: Path, count: int, boxes: str, seed: int) -> Path:
    """The fixed default set: `count` structured and `count` unstructured scenes."""
    d = out / "scenes"
    if d.exists():
        shutil.rmtree(d)
    for kind, s in (("structured", seed), ("unstructured", seed + 1)):
        subprocess.run(_shelfpick() + ["scenes", "--kind", kind, "--count", str(count), "--seed", str(s),
                                       "--out", str(d), "--boxes", boxes], check=True,
                       stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return d


def run_mode(name: str, extra: list[str], scenes: Path, out: Path, args: argparse.Namespace) -> dict:
    d = out / name
    if d.exists():
        shutil.rmtree(d)  # a fresh run, not a resume
    cmd = _shelfpick() + ["bench", str(scenes), "--out", str(d), "--samples", str(args.samples),
                          "--seed", str(args.seed), "--exhaustive-max-boxes", str(args.exhaustive_max_boxes)]
    if args.limit:
        cmd += ["--limit", str(args.limit)]
    cmd += extra
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"{name}: `{' '.join(cmd)}` failed ({proc.returncode}):\n{proc.stderr[-2000:]}")
    recs = read_records(d / "records.jsonl")
    planners = sorted({p for r in recs for p in r["planners"]})
    plan_s = sum(p["plan_s"] for r in recs for p in r["planners"].values())
    return {"mode": name, "command": " ".join(cmd), "wall_s": round(wall, 2), "tasks": len(recs),
            "plans": len(recs) * len(planners),
            "tasks_per_s": round(len(recs) / wall, 4), "plans_per_s": round(len(recs) * len(planners) / wall, 4),
            "sum_plan_s": round(plan_s, 2), "load_avg_start": round(load0, 2),
            "load_avg_end": round(os.getloadavg()[0], 2), "records": recs}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=None, help="folder of scenes (default: generate 2+2 small ones)")
    ap.add_argument("--count", type=int, default=2, help="generated scenes per kind (default 2)")
    ap.add_argument("--boxes", default="8-9", help="boxes per generated scene (default 8-9)")
    ap.add_argument("--limit", type=int, default=None, help="only the first K scenes")
    ap.add_argument("--samples", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2, help="workers for the parallel modes (default 2)")
    ap.add_argument("--exhaustive-max-boxes", type=int, default=0,
                    help="passed to bench (default 0: off, this measures planning throughput)")
    ap.add_argument("--modes", default="serial,workers,ray", help="any of serial,workers,ray")
    ap.add_argument("--out", default="bench-scaling")
    args = ap.parse_args(argv)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    scenes = Path(args.scenes) if args.scenes else make_scenes(out, args.count, args.boxes, 11)
    modes = {"serial": [], "workers": ["--workers", str(args.workers)],
             "ray": ["--ray", "local", "--workers", str(args.workers)]}
    results = []
    for m in (m.strip() for m in args.modes.split(",") if m.strip()):
        if m not in modes:
            raise SystemExit(f"--modes: unknown mode {m!r}")
        name = f"{m}{args.workers}" if m != "serial" else m
        print(f"running {name} ...", flush=True)
        results.append(run_mode(name, modes[m], scenes, out, args))
        r = results[-1]
        print(f"  {r['tasks']} tasks in {r['wall_s']} s: {r['tasks_per_s']} tasks/s, "
              f"{r['plans_per_s']} plans/s", flush=True)

    ref = comparable(results[0]["records"])
    for r in results:
        r["identical_to_" + results[0]["mode"]] = comparable(r["records"]) == ref
    identical = all(r["identical_to_" + results[0]["mode"]] for r in results)
    serial = next((r for r in results if r["mode"] == "serial"), None)
    for r in results:
        r["speedup_vs_serial"] = round(serial["wall_s"] / r["wall_s"], 3) if serial else None
    summary = {"format": "shelfpick.bench-scaling/1", "scenes": str(scenes), "samples": args.samples,
               "seed": args.seed, "workers": args.workers, "cpu_count": os.cpu_count(),
               "identical": identical,
               "modes": [{k: v for k, v in r.items() if k != "records"} for r in results]}
    (out / "scaling.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    lines = [f"# shelfpick bench: serial vs workers vs Ray ({results[0]['tasks']} tasks, {args.samples} samples)", "",
             f"Scenes: `{scenes}`; {os.cpu_count()} CPUs. Records identical in every mode "
             f"(timings aside): **{'yes' if identical else 'NO'}**.", "",
             "| mode | wall (s) | tasks/s | plans/s | speed-up vs serial | load avg (start/end) |",
             "|---|---:|---:|---:|---:|---|"]
    for r in results:
        lines.append(f"| {r['mode']} | {r['wall_s']:.1f} | {r['tasks_per_s']:.3f} | {r['plans_per_s']:.3f} | "
                     f"{r['speedup_vs_serial'] if r['speedup_vs_serial'] is not None else '-'} | "
                     f"{r['load_avg_start']} / {r['load_avg_end']} |")
    lines += ["", "Commands:", ""] + [f"    {r['command']}" for r in results]
    (out / "scaling.md").write_text("\n".join(lines) + "\n", encoding="utf-8")
    print("\n".join(lines))
    return 0 if identical else 1


if __name__ == "__main__":
    raise SystemExit(main())
