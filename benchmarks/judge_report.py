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
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Iterable, Iterator, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

ENGINES = ("pybullet", "mujoco")
# predicted-risk bins of the reliability table: exactly 0, then (lo, hi]
RISK_BINS: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.0, 0.05), (0.05, 0.1), (0.1, 0.2),
                                              (0.2, 0.4), (0.4, 1.0))
TASK_FILTERS = ("all", "exhaustive", "solvable", "unsolvable", "structured", "unstructured")


class UsageError(Exception):
    """A bad argument: one line naming it and its value, exit code 2."""


# --------------------------------------------------------------------------
# tasks
def load_tasks(judge_dir: Path, which: str, limit: int | None) -> list[dict]:
    """The judge's tasks, filtered by a kind (TASK_FILTERS) or a comma list of scene / scene:target names."""
    path = judge_dir / "tasks.json"
    try:
        tasks = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: cannot read the judge's tasks ({exc})") from None
    keep = {
        "all": lambda t: True,
        "exhaustive": lambda t: t["exhaustive"],
        "solvable": lambda t: bool(t.get("min_removals")),
        "unsolvable": lambda t: t["exhaustive"] and not t.get("min_removals"),
        "structured": lambda t: t["kind"] == "structured",
        "unstructured": lambda t: t["kind"] == "unstructured",
    }.get(which)
    if keep is None:
        names = {n.strip() for n in which.split(",") if n.strip()}
        known = {t["scene"] for t in tasks} | {f"{t['scene']}:{t['target']}" for t in tasks}
        unknown = sorted(names - known)
        if unknown:
            raise UsageError(f"--tasks: unknown task {unknown[0]!r} (expected one of {', '.join(TASK_FILTERS)}, "
                             "or scene / scene:target names such as s00,u03:b2)")
        keep = lambda t: t["scene"] in names or f"{t['scene']}:{t['target']}" in names  # noqa: E731
    out = [t for t in tasks if keep(t)]
    return out[:limit] if limit is not None else out


def observe_seed(scene: str) -> int:
    """The perception-error seed evaluate.py gives a scene (s07 / u07 -> 24)."""
    return int(scene[1:]) + 17


def row_key(noise: float, planner: str, task: dict) -> str:
    return f"{noise:g}|{planner}|{task['scene']}:{task['target']}"


# --------------------------------------------------------------------------
# one unit of work (runs in a worker process)
_JUDGES: dict[str, Any] = {}


def init_worker(judge_dir: str) -> None:
    """Make the judge importable here (a spawned worker starts with a fresh sys.path)."""
    if judge_dir not in sys.path:
        sys.path.insert(0, judge_dir)
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    os.environ.setdefault("MPLBACKEND", "Agg")


def judge_fn(engine: str):
    """The judge's own entry point for an engine, imported once per process."""
    if engine not in _JUDGES:
        if engine == "mujoco":
            from judge_mujoco import judge_mj
            _JUDGES[engine] = judge_mj
        else:
            from judge import judge
            _JUDGES[engine] = judge
    return _JUDGES[engine]


def cli_plan_settings(overrides: dict) -> dict:
    """What `shelfpick plan` passes to make_plan by default (its parser's defaults), with overrides."""
    from planning import cmd_plan

    parser = argparse.ArgumentParser()
    cmd_plan.add_arguments(parser)
    args = parser.parse_args(["scene.json", "--target", "x"])
    settings = {"samples": args.samples, "seed": args.seed, "risk": args.risk,
                "budget_s": args.budget, "workers": args.workers or 1}  # None: the CLI picks by cores; --jobs already uses them
    settings.update({k: v for k, v in overrides.items() if v is not None})
    return settings


def make_timed_plan(obs: dict, target: str, planner: str, settings: dict) -> tuple[dict, dict]:
    """make_plan on the observed scene, in this process; (plan fields for the row, plan document)."""
    from perception.errors import ShelfpickError
    from perception.scene import Scene
    from planning.planner import make_plan

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        try:
            plan = make_plan(Scene.from_json(obs, "observed"), "extract", target, planner=planner, **settings)
        except ShelfpickError as exc:
            return {"plan_s": round(time.perf_counter() - t0, 4), "error": str(exc)[:300]}, {}
        plan_s = time.perf_counter() - t0
    check = plan.extra.get("scene_check") if isinstance(plan.extra, dict) else None
    fields = {"plan_s": round(plan_s, 4), "sequence": list(plan.sequence), "declared_safe": bool(plan.safe),
              "risk": round(plan.risk, 4),
              "step_risk": [round(p.risk, 4) for p in plan.predicted],
              "step_collapse_prob": [round(p.collapse_prob, 4) for p in plan.predicted],
              "warnings": [str(w.message)[:200] for w in caught][:5]}
    if isinstance(check, dict) and "stands_as_seen" in check:
        fields["stands_as_seen"] = bool(check["stands_as_seen"])
    return fields, plan.to_json()


def judged(engine: str, truth: dict, plan_doc: dict) -> dict:
    """The judge's verdict, kept to what the report needs (per-step collapse for reliability)."""
    t0 = time.perf_counter()
    v = judge_fn(engine)(truth, plan_doc)
    return {"ok": bool(v["ok"]), "first_collapse_step": v.get("first_collapse_step"),
            "n_removed": v.get("n_removed"),
            "step_collapse": [bool(s.get("collapse")) for s in v.get("steps", [])],
            "step_moved": [list(s.get("moved", [])) for s in v.get("steps", [])],
            "judge_s": round(time.perf_counter() - t0, 3)}


def run_unit(unit: dict) -> dict:
    """Observe, plan (timed), judge with every engine asked for: one row."""
    from observe import observed

    task, noise, planner = unit["task"], unit["noise"], unit["planner"]
    judge_dir = Path(unit["judge_dir"])
    truth = json.loads((judge_dir / "scenes" / f"{task['scene']}.json").read_text(encoding="utf-8"))
    obs = observed(truth, noise=noise, seed=observe_seed(task["scene"]))
    row: dict[str, Any] = {
        "key": row_key(noise, planner, task), "scene": task["scene"], "target": task["target"],
        "kind": task["kind"], "n_boxes": task.get("n_boxes"), "noise": noise, "planner": planner,
        "exhaustive": task["exhaustive"],
        "min_removals": len(task["min_removals"]) if task.get("min_removals") else None,
        "settings": unit["settings_id"]}
    fields, plan_doc = make_timed_plan(obs, task["target"], planner, unit["settings"])
    row.update(fields)
    row["judges"] = {e: judged(e, truth, plan_doc) for e in unit["engines"]} if plan_doc else {}
    return row


def init_and_run(unit: dict) -> dict:
    init_worker(unit["judge_dir"])
    return run_unit(unit)


# --------------------------------------------------------------------------
# rows: write, resume
def read_rows(path: Path) -> list[dict]:
    """Rows already written; a torn last line is dropped, a repeated key keeps the last."""
    if not path.exists():
        return []
    rows: dict[str, dict] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            r = json.loads(line)
        except ValueError:
            continue
        if isinstance(r, dict) and isinstance(r.get("key"), str):
            rows[r["key"]] = r
    return list(rows.values())


def iter_rows(units: Sequence[dict], jobs: int) -> Iterator[dict]:
    """Rows as units finish: in this process, or in `jobs` spawned processes (no forked PyBullet)."""
    if jobs <= 1:
        for u in units:
            yield init_and_run(u)
        return
    import multiprocessing as mp

    with mp.get_context("spawn").Pool(jobs, initializer=init_worker, initargs=(units[0]["judge_dir"],)) as pool:
        yield from pool.imap_unordered(run_unit, units, chunksize=1)


# --------------------------------------------------------------------------
# summary
def percentile(values: Sequence[float], q: float) -> float:
    v = sorted(values)
    if not v:
        return float("nan")
    k = (len(v) - 1) * q
    lo = int(k)
    hi = min(lo + 1, len(v) - 1)
    return v[lo] + (v[hi] - v[lo]) * (k - lo)


def _mean(xs: Sequence[float]) -> float:
    return sum(xs) / len(xs) if xs else float("nan")


def engine_summary(rows: Sequence[dict], engine: str) -> dict:
    """evaluate.py's figures for one engine's verdicts on these rows."""
    held = lambda r: bool(r.get("judges", {}).get(engine, {}).get("ok"))  # noqa: E731
    ok = [r for r in rows if held(r)]
    feasible = [r for r in rows if r["min_removals"]]
    feasible_ok = [r for r in feasible if held(r)]
    said_safe = [r for r in rows if r.get("declared_safe")]
    safe_collapsed = [r for r in said_safe if not held(r)]
    infeasible = [r for r in rows if r["exhaustive"] and not r["min_removals"]]
    removed = _mean([len(r["sequence"]) for r in feasible_ok])
    minimum = _mean([r["min_removals"] for r in feasible_ok])
    by_kind = {k: [sum(1 for r in ok if r["kind"] == k), sum(1 for r in rows if r["kind"] == k)]
               for k in ("structured", "unstructured")}
    return {"tasks": len(rows), "ok": len(ok), "solvable": len(feasible), "solvable_ok": len(feasible_ok),
            "removed": removed, "min_removals": minimum,
            "removed_ratio": removed / minimum if minimum and minimum == minimum else float("nan"),
            "declared_safe": len(said_safe), "declared_safe_collapsed": len(safe_collapsed),
            "unsolvable": len(infeasible),
            "unsolvable_flagged": sum(1 for r in infeasible if not r.get("declared_safe", True)),
            "plan_errors": sum(1 for r in rows if "error" in r), "by_kind": by_kind}


def evaluate_line(planner: str, noise: float, engine: str, s: dict) -> str:
    """The summary line as evaluate.py prints it (same wording, same numbers)."""
    return (f"{planner}, noise {noise * 100:.1f} cm, {engine} judge: ok {s['ok']}/{s['tasks']}; "
            f"exhaustively solvable tasks ok {s['solvable_ok']}/{s['solvable']}, removing "
            f"{s['removed']:.2f} vs minimum {s['min_removals']:.2f}; "
            f"declared safe but collapsed {s['declared_safe_collapsed']}/{s['declared_safe']}; "
            f"unsolvable tasks flagged unsafe {s['unsolvable_flagged']}/{s['unsolvable']}")


def risk_bin(risk: float) -> int:
    """Index into RISK_BINS: 0 for exactly 0, then the (lo, hi] bin holding `risk`."""
    if risk <= 0.0:
        return 0
    for i, (lo, hi) in enumerate(RISK_BINS[1:], start=1):
        if lo < risk <= hi:
            return i
    return len(RISK_BINS) - 1


def bin_label(i: int) -> str:
    lo, hi = RISK_BINS[i]
    return "0" if i == 0 else f"({lo:g}, {hi:g}]"


def judged_steps(rows: Iterable[dict], engine: str) -> Iterator[tuple[float, bool]]:
    """(predicted risk, judge saw a collapse) for every step up to and including the first collapse."""
    for r in rows:
        v = r.get("judges", {}).get(engine)
        if not v:
            continue
        for risk, collapsed in zip(r.get("step_risk", []), v["step_collapse"]):
            yield risk, collapsed
            if collapsed:
                break


def reliability(rows: Iterable[dict], engine: str) -> list[dict]:
    """Per risk bin: steps, mean predicted risk, collapses seen by the judge, their frequency."""
    acc = [[0, 0.0, 0] for _ in RISK_BINS]
    for risk, collapsed in judged_steps(rows, engine):
        a = acc[risk_bin(risk)]
        a[0] += 1
        a[1] += risk
        a[2] += int(collapsed)
    return [{"bin": bin_label(i), "steps": n, "predicted": s / n if n else float("nan"),
             "collapses": k, "observed": k / n if n else float("nan")} for i, (n, s, k) in enumerate(acc)]


def engine_agreement(rows: Sequence[dict]) -> dict:
    """Plans judged by both engines: how many hold in only one of them."""
    both = [r for r in rows if all(e in r.get("judges", {}) for e in ENGINES)]
    pb_only = sum(1 for r in both if r["judges"]["pybullet"]["ok"] and not r["judges"]["mujoco"]["ok"])
    mj_only = sum(1 for r in both if r["judges"]["mujoco"]["ok"] and not r["judges"]["pybullet"]["ok"])
    return {"plans": len(both), "pybullet_only": pb_only, "mujoco_only": mj_only}


def groups(rows: Sequence[dict]) -> dict[tuple[float, str], list[dict]]:
    out: dict[tuple[float, str], list[dict]] = {}
    for r in sorted(rows, key=lambda r: (r["noise"], r["planner"], r["scene"], r["target"])):
        out.setdefault((r["noise"], r["planner"]), []).append(r)
    return out


def summarize(rows: Sequence[dict], engines: Sequence[str]) -> dict:
    """Everything the report prints, as plain data (results JSON)."""
    out: dict[str, Any] = {"groups": [], "reliability": []}
    for (noise, planner), rs in groups(rows).items():
        times = [r["plan_s"] for r in rs if "plan_s" in r]
        g = {"noise": noise, "planner": planner, "plan_p50_s": percentile(times, 0.5),
             "plan_p90_s": percentile(times, 0.9), "engines": {e: engine_summary(rs, e) for e in engines}}
        if all(e in engines for e in ENGINES):
            g["agreement"] = engine_agreement(rs)
        out["groups"].append(g)
    for noise in sorted({r["noise"] for r in rows}):
        for engine in engines:
            at = [r for r in rows if r["noise"] == noise]
            out["reliability"].append({
                "noise": noise, "engine": engine, "all": reliability(at, engine),
                "physics": reliability([r for r in at if r["planner"] == "physics"], engine)})
    return out


# --------------------------------------------------------------------------
# report
def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / n:.0f}%)" if n else f"{k}/0"


def _f(x: float, fmt: str = "{:.2f}") -> str:
    return "-" if x != x else fmt.format(x)


def to_markdown(summary: dict, header: str = "") -> str:
    """The report: evaluate.py's lines, a table per group, engine agreement, reliability tables."""
    lines = [header, ""] if header else []
    for g in summary["groups"]:
        for e, s in g["engines"].items():
            lines.append("    " + evaluate_line(g["planner"], g["noise"], e, s))
    lines += ["", "| noise | planner | engine | ok | structured | unstructured | solvable ok | removed vs min "
              "| declared safe, collapsed | unsolvable flagged | plan errors | plan p50 / p90 s |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for g in summary["groups"]:
        for e, s in g["engines"].items():
            bk = s["by_kind"]
            lines.append(
                f"| {g['noise']:g} | {g['planner']} | {e} | {_pct(s['ok'], s['tasks'])} "
                f"| {_pct(*bk['structured'])} | {_pct(*bk['unstructured'])} "
                f"| {_pct(s['solvable_ok'], s['solvable'])} "
                f"| {_f(s['removed'])} vs {_f(s['min_removals'])} (x{_f(s['removed_ratio'])}) "
                f"| {_pct(s['declared_safe_collapsed'], s['declared_safe'])} "
                f"| {s['unsolvable_flagged']}/{s['unsolvable']} | {s['plan_errors']} "
                f"| {_f(g['plan_p50_s'])} / {_f(g['plan_p90_s'])} |")
    agree = [g for g in summary["groups"] if "agreement" in g]
    if agree:
        lines += ["", "Plans that hold in only one engine (the same plan judged by both):", "",
                  "| noise | planner | plans | ok in pybullet only | ok in mujoco only |", "|---|---|---|---|---|"]
        for g in agree:
            a = g["agreement"]
            lines.append(f"| {g['noise']:g} | {g['planner']} | {a['plans']} | {a['pybullet_only']} "
                         f"| {a['mujoco_only']} |")
    for rel in summary["reliability"]:
        lines += ["", f"Reliability, noise {rel['noise']:g}, {rel['engine']} judge: every step up to and "
                  "including the judge's first collapse, by predicted risk", "",
                  "| predicted risk | steps (all planners) | mean predicted | collapses | observed "
                  "| physics steps | physics observed |", "|---|---|---|---|---|---|---|"]
        for a, p in zip(rel["all"], rel["physics"]):
            lines.append(f"| {a['bin']} | {a['steps']} | {_f(a['predicted'], '{:.3f}')} | {a['collapses']} "
                         f"| {_f(a['observed'], '{:.3f}')} | {p['steps']} | {_f(p['observed'], '{:.3f}')} |")
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: Path) -> None:
    """Reliability diagram: observed collapse frequency against mean predicted risk, one panel per noise."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    noises = sorted({r["noise"] for r in summary["reliability"]})
    fig, axes = plt.subplots(1, max(1, len(noises)), figsize=(5.5 * max(1, len(noises)), 5), squeeze=False)
    for ax, noise in zip(axes[0], noises):
        ax.plot([0, 1], [0, 1], color="0.7", lw=1, ls="--", label="calibrated")
        for rel in (r for r in summary["reliability"] if r["noise"] == noise):
            for pool, style in (("all", "-o"), ("physics", ":s")):
                pts = [b for b in rel[pool] if b["steps"]]
                if not pts:
                    continue
                xs, ys = [b["predicted"] for b in pts], [b["observed"] for b in pts]
                line, = ax.plot(xs, ys, style, label=f"{rel['engine']}, {pool} steps")
                for b, x, y in zip(pts, xs, ys):
                    ax.annotate(str(b["steps"]), (x, y), textcoords="offset points", xytext=(4, 4),
                                fontsize=7, color=line.get_color())
        ax.set(xlim=(-0.02, 1.02), ylim=(-0.02, 1.02), xlabel="predicted risk (bin mean)",
               ylabel="collapse frequency on the judge", title=f"noise {noise * 100:g} cm (labels: steps)")
        ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --------------------------------------------------------------------------
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"),
                    help="the independent judge's folder (default ../shared/judge)")
    ap.add_argument("--noise", default="0", help="comma list of perception-error levels in m (default 0)")
    ap.add_argument("--engine", choices=("pybullet", "mujoco", "both"), default="pybullet")
    ap.add_argument("--planners", default="physics", help="comma list: physics, heuristic (default physics)")
    ap.add_argument("--tasks", default="all",
                    help=f"{', '.join(TASK_FILTERS)}, or a comma list of scene / scene:target (default all)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N tasks (after --tasks)")
    ap.add_argument("--samples", type=int, default=None, help="make_plan samples (default: shelfpick plan's)")
    ap.add_argument("--risk", type=float, default=None, help="make_plan risk (default: shelfpick plan's)")
    ap.add_argument("--jobs", type=int, default=1, help="processes over tasks (spawned; default 1)")
    ap.add_argument("--out", default=None, help="rows (JSONL); the report goes to <out>.md, the plot to <out>.png")
    ap.add_argument("--resume", action="store_true", help="keep rows already in --out made with the same settings")
    ap.add_argument("--plot", default=None, help="reliability plot (PNG; default <out>.png, none without --out)")
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
    engines = list(ENGINES) if a.engine == "both" else [a.engine]
    return noises, planners, engines


def build_units(a: argparse.Namespace, noises: list[float], planners: list[str],
                engines: list[str]) -> tuple[list[dict], str]:
    """Every (noise, planner, task) to run, and the settings id that rows must match to be reused."""
    judge_dir = str(Path(a.judge_dir).resolve())
    tasks = load_tasks(Path(judge_dir), a.tasks, a.limit)
    settings = cli_plan_settings({"samples": a.samples, "risk": a.risk})
    settings_id = json.dumps({"plan": settings, "engines": engines}, sort_keys=True)
    units = [{"task": t, "noise": n, "planner": p, "engines": engines, "settings": settings,
              "settings_id": settings_id, "judge_dir": judge_dir}
             for n in noises for p in planners for t in tasks]
    # the slowest (largest shelves) first keeps both processes busy to the end
    units.sort(key=lambda u: -(u["task"].get("n_boxes") or 0))
    return units, settings_id


def run(a: argparse.Namespace) -> dict:
    noises, planners, engines = check_args(a)
    units, settings_id = build_units(a, noises, planners, engines)
    out = Path(a.out) if a.out else None
    keys = {u["task"]["scene"] + ":" + u["task"]["target"] for u in units}
    rows: list[dict] = []
    if out and a.resume:
        wanted = {row_key(u["noise"], u["planner"], u["task"]) for u in units}
        rows = [r for r in read_rows(out) if r.get("settings") == settings_id and r["key"] in wanted]
    done = {r["key"] for r in rows}
    todo = [u for u in units if row_key(u["noise"], u["planner"], u["task"]) not in done]
    print(f"judge_report: {len(keys)} tasks x {len(noises)} noise x {len(planners)} planners, engines "
          f"{'+'.join(engines)}; {len(rows)} rows kept, {len(todo)} to run on {a.jobs} process(es)",
          file=sys.stderr)
    t0 = time.perf_counter()
    f = None
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        f = open(out, "w", encoding="utf-8")
        for r in rows:
            f.write(json.dumps(r) + "\n")
        f.flush()
    try:
        for i, row in enumerate(iter_rows(todo, a.jobs) if todo else (), start=1):
            rows.append(row)
            if f:
                f.write(json.dumps(row) + "\n")
                f.flush()
            oks = " ".join(f"{e}={'ok' if v['ok'] else 'FAIL'}" for e, v in row["judges"].items())
            print(f"[{i}/{len(todo)}] {row['key']} plan {row['plan_s']:.2f}s "
                  f"{'safe' if row.get('declared_safe') else 'UNSAFE'} {oks or row.get('error', '')}",
                  file=sys.stderr, flush=True)
    finally:
        if f:
            f.close()
    summary = summarize(rows, engines)
    summary["run"] = {"wall_s": round(time.perf_counter() - t0, 1), "jobs": a.jobs, "rows": len(rows),
                      "settings": json.loads(settings_id)}
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    a = parse_args(argv)
    try:
        summary = run(a)
    except UsageError as exc:
        print(f"judge_report: {exc}", file=sys.stderr)
        return 2
    run_info = summary["run"]
    header = (f"judge_report: {run_info['rows']} rows, plan settings {json.dumps(run_info['settings']['plan'])}, "
              f"{run_info['wall_s']} s on {run_info['jobs']} process(es)")
    text = to_markdown(summary, header)
    print(text, end="")
    if a.out:
        Path(a.out).with_suffix(".md").write_text(text, encoding="utf-8")
        Path(a.out).with_suffix(".summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    plot_path = a.plot or (str(Path(a.out).with_suffix(".png")) if a.out else None)
    if plot_path:
        plot(summary, Path(plot_path))
        print(f"wrote {plot_path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
