"""Plans made in-process by `make_plan`, judged by the independent judge in ../shared/judge.

The judge is not ours and is never copied: it is imported at run time from `--judge-dir`.
For every task of its tasks.json, at each `--noise` level and for each planner:
the true scene goes through the judge's own `observe.py` (front faces, depth
unknown, no masses, `noise` m of perception error, seeded as its evaluate.py
seeds it), `make_plan` plans on that with the settings `shelfpick plan` would use
(its parser's defaults: same plans as `evaluate.py --shelfpick .venv/bin/shelfpick`),
timed, and the plan is executed on the TRUE scene by the judge's PyBullet engine,
its MuJoCo engine, or both (`--engine both`: the same plan judged twice).

Reported per noise level, planner and engine: the summary line evaluate.py
prints (ok, solvable ok, removals vs minimum, declared safe but collapsed,
unsolvable flagged), plan time p50/p90, plans that hold in only one engine, and a
reliability table: every plan step up to and including the judge's first collapse,
binned by its predicted risk, against how often the judge saw a collapse at that
step; the same as a matplotlib plot.

    .venv/bin/python benchmarks/judge_report.py --judge-dir ../shared/judge --noise 0 --engine pybullet \\
        --jobs 2 --out judge-n0.jsonl
    .venv/bin/python benchmarks/judge_report.py --judge-dir ../shared/judge --noise 0,0.01 --engine both \\
        --planners physics,heuristic --jobs 2 --out judge.jsonl [--resume] [--limit 10] [--tasks solvable]

Writes `--out` rows (one JSON line per (noise, planner, task), flushed as each
finishes; `--resume` keeps the rows already there that were made with the same
settings), `<out>.md` (the report) and `<out>.png` (the reliability plot).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

# the pieces: rows (tasks, one unit observed/planned/judged, the rows file), their arithmetic,
# the markdown and the plot; the names are kept here too for callers of this module
from benchmarks.judge_markdown import to_markdown  # noqa: E402
from benchmarks.judge_plot import plot  # noqa: E402
from benchmarks.judge_rows import (TASK_FILTERS, UsageError, cli_plan_settings, collect_rows,  # noqa: E402
                                   clear_tasks, kept_rows, load_tasks, print_report, read_rows, row_key, run_unit)
from benchmarks.judge_summary import (ENGINES, RISK_BINS, engine_agreement, engine_summary,  # noqa: E402
                                      evaluate_line, percentile, reliability, risk_bin, summarize)

__all__ = ["ENGINES", "RISK_BINS", "TASK_FILTERS", "UsageError", "build_units", "check_args", "engine_agreement",
           "engine_summary", "evaluate_line", "load_tasks", "main", "parse_args", "percentile", "plot",
           "read_rows", "reliability", "risk_bin", "row_key", "run", "run_unit", "summarize", "to_markdown"]


# --------------------------------------------------------------------------
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"),
                    help="the independent judge's folder (default ../shared/judge)")
    ap.add_argument("--noise", default="0", help="comma list of perception-error levels in m (default 0)")
    ap.add_argument("--engine", choices=("pybullet", "mujoco", "both"), default="pybullet")
    ap.add_argument("--planners", default="physics", help="comma list: physics, heuristic (default physics)")
    ap.add_argument("--tasks", default="all",
                    help=f"{', '.join(TASK_FILTERS)}, or a comma list of scene / scene:target (default all)")
    ap.add_argument("--task", choices=("extract", "clear"), default="extract",
                    help="extract the tasks' targets (default) or clear each of their shelves (ok: every box out)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N tasks (after --tasks)")
    ap.add_argument("--samples", type=int, default=None, help="make_plan samples (default: shelfpick plan's)")
    ap.add_argument("--risk", type=float, default=None, help="make_plan risk (default: shelfpick plan's)")
    ap.add_argument("--seed", type=int, default=None,
                    help="make_plan seed (default: shelfpick plan's): rerun with others to see how many "
                         "verdicts the draws alone change")
    ap.add_argument("--physics", default=None,
                    help="JSON of PhysicsConfig fields for the planner's worlds (a lever to measure; default none)")
    ap.add_argument("--jobs", type=int, default=1, help="processes over tasks (spawned; default 1)")
    ap.add_argument("--out", default=None, help="rows (JSONL); the report goes to <out>.md, the plot to <out>.png")
    ap.add_argument("--resume", action="store_true", help="keep rows already in --out made with the same settings")
    ap.add_argument("--plot", default=None, help="reliability plot (PNG; default <out>.png, none without --out)")
    ap.add_argument("--see-truth", action="store_true",
                    help="diagnostic: plan from the true shelf (depths and masses known, no perception error) "
                         "instead of the camera's view: the ceiling of what prediction can gain")
    return ap.parse_args(argv)


def check_args(a: argparse.Namespace) -> tuple[list[float], list[str], list[str]]:
    """Validated noise levels, planners and engines; UsageError naming the bad one."""
    try:
        noises = [float(x) for x in a.noise.split(",") if x.strip()]
    except ValueError:
        raise UsageError(f"--noise: expected a comma list of metres, got {a.noise!r}") from None
    if not noises or any(not math.isfinite(n) or n < 0 or n > 0.1 for n in noises):
        raise UsageError(f"--noise: expected metres in [0, 0.1], got {a.noise!r}")
    planners = [p.strip() for p in a.planners.split(",") if p.strip()]
    if not planners or any(p not in ("physics", "heuristic") for p in planners):
        raise UsageError(f"--planners: expected physics and/or heuristic, got {a.planners!r}")
    for name in ("limit", "jobs", "samples"):
        v = getattr(a, name)
        if v is not None and v < 1:
            raise UsageError(f"--{name}: expected a positive integer, got {v!r}")
    if a.risk is not None and not 0.0 <= a.risk <= 1.0:
        raise UsageError(f"--risk: expected a probability in [0, 1], got {a.risk!r}")
    judge_dir = Path(a.judge_dir)
    for f in ("judge.py", "observe.py", "tasks.json"):
        if not (judge_dir / f).is_file():
            raise UsageError(f"--judge-dir: {judge_dir} has no {f} (the independent judge's folder)")
    if a.resume and not a.out:
        raise UsageError("--resume: needs --out (the rows to continue)")
    if a.physics is not None:
        from shelfpick.planning.physics import PhysicsConfig
        try:
            fields = json.loads(a.physics)
            PhysicsConfig(**fields)
        except (ValueError, TypeError):
            raise UsageError(f"--physics: expected a JSON object of PhysicsConfig fields, got {a.physics!r}") from None
    engines = list(ENGINES) if a.engine == "both" else [a.engine]
    return noises, planners, engines


def build_units(a: argparse.Namespace, noises: list[float], planners: list[str],
                engines: list[str]) -> tuple[list[dict], str]:
    """Every (noise, planner, task) to run, and the settings id that rows must match to be reused."""
    judge_dir = str(Path(a.judge_dir).resolve())
    tasks = load_tasks(Path(judge_dir), a.tasks, None)
    if a.task == "clear":
        tasks = clear_tasks(tasks)
    tasks = tasks[:a.limit] if a.limit is not None else tasks
    settings = cli_plan_settings({"samples": a.samples, "risk": a.risk, "seed": a.seed,
                                  "physics": json.loads(a.physics) if a.physics else None})
    ident = {"plan": settings, "engines": engines, **({"see_truth": True} if a.see_truth else {})}
    settings_id = json.dumps(ident, sort_keys=True)
    units = [{"task": t, "noise": n, "planner": p, "engines": engines, "settings": settings,
              "settings_id": settings_id, "judge_dir": judge_dir, "see_truth": bool(a.see_truth)}
             for n in noises for p in planners for t in tasks]
    # the slowest (largest shelves) first keeps both processes busy to the end
    units.sort(key=lambda u: -(u["task"].get("n_boxes") or 0))
    return units, settings_id


def run(a: argparse.Namespace) -> dict:
    """Keep the rows `--resume` allows, run the rest (rows written as they finish), summarize them all."""
    noises, planners, engines = check_args(a)
    units, settings_id = build_units(a, noises, planners, engines)
    out = Path(a.out) if a.out else None
    keys = {u["task"]["scene"] + ":" + (u["task"]["target"] or "clear") for u in units}
    rows = kept_rows(out, a.resume, settings_id, {row_key(u["noise"], u["planner"], u["task"]) for u in units})
    done = {r["key"] for r in rows}
    todo = [u for u in units if row_key(u["noise"], u["planner"], u["task"]) not in done]
    print(f"judge_report: {len(keys)} tasks x {len(noises)} noise x {len(planners)} planners, engines "
          f"{'+'.join(engines)}; {len(rows)} rows kept, {len(todo)} to run on {a.jobs} process(es)",
          file=sys.stderr)
    t0 = time.perf_counter()
    collect_rows(rows, todo, a.jobs, out)
    summary = summarize(rows, engines)
    summary["run"] = {"wall_s": round(time.perf_counter() - t0, 1), "jobs": a.jobs, "rows": len(rows),
                      "settings": json.loads(settings_id)}
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Run, print and write the report (<out>.md, <out>.summary.json) and the plot; 2 on a bad argument."""
    a = parse_args(argv)

    def header(summary: dict) -> str:
        r = summary["run"]
        return (f"judge_report: {r['rows']} rows, plan settings {json.dumps(r['settings']['plan'])}, "
                f"{r['wall_s']} s on {r['jobs']} process(es)")
    summary = print_report("judge_report", run, a, header, to_markdown, Path(a.out).with_suffix(".md") if a.out else None)
    if summary is None:
        return 2
    if a.out:
        Path(a.out).with_suffix(".summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    plot_path = a.plot or (str(Path(a.out).with_suffix(".png")) if a.out else None)
    if plot_path:
        plot(summary, Path(plot_path))
        print(f"wrote {plot_path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
