"""The benchmark's report: the summary of its records, as JSON, Markdown and a plot.

Kept apart from the run (`planning/bench.py`) so that a report can be made again
from a records file without running anything.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Sequence

from shelfpick.perception.scene import write_json
from shelfpick.planning.bench_config import BenchConfig

# fields of a record that are measurements of the machine, not results
TIMING_KEYS = ("plan_s", "setup_s", "exec_wall_s", "exhaustive_s", "worker")

def percentile(values: Sequence[float], q: float) -> float | None:
    """Linear-interpolated quantile `q` of `values` (None when empty)."""
    if not values:
        return None
    v = sorted(values)
    k = (len(v) - 1) * q
    lo, hi = math.floor(k), math.ceil(k)
    return v[lo] + (v[hi] - v[lo]) * (k - lo)


def _mean(values: Sequence[float]) -> float | None:
    return sum(values) / len(values) if values else None


def _exhaustive_summary(records: Sequence[dict], config: BenchConfig) -> dict:
    """On scenes small enough for the exhaustive search: is the task solvable on the truth, and
    per planner its success there, its gap to the minimum and the unsolvable tasks it flagged."""
    small = [r for r in records if r.get("exhaustive")]
    exh: dict[str, Any] = {"tasks": len(small), "max_boxes": config.exhaustive_max_boxes}
    if small:
        feas = [r for r in small if r["exhaustive"]["feasible"]]
        infeasible = [r for r in small if not r["exhaustive"]["feasible"]]
        exh["feasible_rate"] = len(feas) / len(small)
        exh["feasible_tasks"] = len(feas)
        for planner in config.planners:
            rows = [r for r in feas if planner in r["planners"]]
            if not rows:
                continue
            ok = [r for r in rows if r["planners"][planner]["ok"]]
            exh[planner] = {
                "infeasible_flagged": sum(not r["planners"][planner].get("safe", True)
                                          for r in infeasible if planner in r["planners"]),
                "infeasible_tasks": len(infeasible),
                "success_rate_on_feasible": len(ok) / len(rows),
                "mean_gap_removals": _mean([r["planners"][planner]["removed"] - r["exhaustive"]["min_removals"]
                                            for r in ok]),
                "optimal_rate": (sum(r["planners"][planner]["removed"] == r["exhaustive"]["min_removals"]
                                     for r in ok) / len(ok)) if ok else None,
            }
    return exh


def summarize(records: Sequence[dict], config: BenchConfig) -> dict:
    """Per planner and kind (and 'all'): success, removals, robot time, planning time, displacement."""
    all_records = sorted(records, key=lambda r: r["key"])  # same sums in the same order, however it ran
    records = [r for r in all_records if not r.get("no_truth")]
    kinds = sorted({r["kind"] for r in records})
    groups = {k: [r for r in records if r["kind"] == k] for k in kinds}
    if len(kinds) > 1:
        groups["all"] = list(records)
    table: dict[str, dict[str, dict]] = {}
    for kind, recs in groups.items():
        table[kind] = {}
        for planner in config.planners:
            rows = [r["planners"][planner] for r in recs if planner in r.get("planners", {})]
            if not rows:
                continue
            removed = [p["removed"] for p in rows]
            table[kind][planner] = {
                "tasks": len(rows),
                "success_rate": sum(p["ok"] for p in rows) / len(rows),
                "mean_removed": _mean(removed),
                "mean_exec_time_s": _mean([n * config.robot_time for n in removed]),
                "plan_p50_s": percentile([p["plan_s"] for p in rows], 0.5),
                "plan_p90_s": percentile([p["plan_s"] for p in rows], 0.9),
                "mean_disp_per_step_m": _mean([p["mean_disp"] for p in rows]),
                "declared_safe": sum(bool(p.get("safe")) for p in rows),
                "declared_safe_collapsed": sum(bool(p.get("safe")) and not p["ok"] for p in rows),
                "plan_errors": sum("error" in p for p in rows),
            }
        pa, bh = table[kind].get("physics"), table[kind].get("heuristic")
        if pa and bh:
            t_pa, t_bh = pa["mean_exec_time_s"], bh["mean_exec_time_s"]
            table[kind]["relative"] = {
                "success_rate_ratio": (pa["success_rate"] / bh["success_rate"]) if bh["success_rate"] else None,
                "success_rate_gain": pa["success_rate"] - bh["success_rate"],
                "efficiency": (t_bh - t_pa) / t_pa if t_pa else None,
            }
    exh = _exhaustive_summary(records, config)
    no_truth = [r for r in all_records if r.get("no_truth")]
    return {"format": "shelfpick.bench-results/1", "config": config.to_json(), "table": table,
            "exhaustive": exh, "scenes": len({r["scene"] for r in records}), "tasks": len(records),
            "no_truth": {"tasks": len(no_truth), "scenes": sorted({r["scene"] for r in no_truth})}}


def _f(v: Any, fmt: str = "{:.2f}") -> str:
    return "-" if v is None else fmt.format(v)


def _share(k: int | None, n: int | None) -> str:
    return "-" if not n else f"{k}/{n} ({100 * (k or 0) / n:.0f}%)"


def _truth_line(truth: dict | None) -> str:
    """One sentence on what the plans were judged against."""
    if not truth:
        return ("Plans made with depths hidden, executed on the true scene in the planner's own physics "
                "(`--truth nominal`: flatters the planner).")
    return (f"Plans made from front faces only ({truth['noise'] * 100:g} cm perception error, depth and mass "
            f"unknown), executed on the true shelf with true masses {truth['mass'][0]:g}-{truth['mass'][1]:g} kg, "
            f"friction {truth['friction'][0]:g}-{truth['friction'][1]:g}, a pull at "
            f"{truth['pull_speed'][0]:g}-{truth['pull_speed'][1]:g} m/s limited to "
            f"{truth['pull_force'][0]:g}-{truth['pull_force'][1]:g} N, lift {truth['pull_lift'] * 1000:g} mm "
            "(drawn per scene).")


def to_markdown(summary: dict) -> str:
    cfg = summary["config"]
    lines = [f"# shelfpick bench: {summary['scenes']} scenes, {summary['tasks']} tasks",
             "",
             f"planners {', '.join(cfg['planners'])}; {cfg['samples']} depth samples; seed {cfg['seed']}; "
             f"robot time {cfg['robot_time']} s per removed box. {_truth_line(cfg.get('truth'))}",
             "",
             "| kind | planner | tasks | success | boxes removed | exec time (s) | plan p50 (s) | plan p90 (s) "
             "| displacement/step (mm) | declared safe, collapsed | no plan |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for kind, rows in summary["table"].items():
        for planner, r in rows.items():
            if planner == "relative":
                continue
            lines.append(f"| {kind} | {planner} | {r['tasks']} | {_f(r['success_rate'] * 100, '{:.1f}%')} | "
                         f"{_f(r['mean_removed'])} | {_f(r['mean_exec_time_s'], '{:.1f}')} | "
                         f"{_f(r['plan_p50_s'], '{:.3f}')} | {_f(r['plan_p90_s'], '{:.3f}')} | "
                         f"{_f(None if r['mean_disp_per_step_m'] is None else r['mean_disp_per_step_m'] * 1000, '{:.1f}')} | "
                         f"{_share(r.get('declared_safe_collapsed'), r.get('declared_safe'))} | {r.get('plan_errors', 0)} |")
    hf = [(k, v["heuristic"]) for k, v in summary["table"].items() if "heuristic" in v]
    if hf:
        lines += ["", "Highest-first fails on: " + ", ".join(
            f"{k} {r['tasks'] - round(r['success_rate'] * r['tasks'])}/{r['tasks']} "
            f"({_f((1 - r['success_rate']) * 100, '{:.0f}%')})" for k, r in hf) + "."]
    rel = [(k, v["relative"]) for k, v in summary["table"].items() if "relative" in v]
    if rel:
        lines += ["", "Physics-aware relative to the height heuristic (efficiency = (T_bh - T_pa) / T_pa):", "",
                  "| kind | success physics - heuristic | success ratio | efficiency |", "|---|---:|---:|---:|"]
        for k, r in rel:
            lines.append(f"| {k} | {_f(r['success_rate_gain'] * 100, '{:+.1f} pp')} | "
                         f"{_f(r['success_rate_ratio'], '{:.2f}x')} | {_f(r['efficiency'] * 100 if r['efficiency'] is not None else None, '{:+.1f}%')} |")
    e = summary["exhaustive"]
    if e.get("tasks"):
        lines += ["", f"Exhaustive search on the true scene (scenes of <= {e['max_boxes']} boxes, {e['tasks']} tasks): "
                  f"a collapse-free order exists for {_f(e['feasible_rate'] * 100, '{:.1f}%')} ({e['feasible_tasks']} tasks).", "",
                  "| planner | success on feasible tasks | mean gap to the minimum (successes) | optimal "
                  "| unsolvable flagged unsafe |",
                  "|---|---:|---:|---:|---:|"]
        for p in cfg["planners"]:
            if p in e:
                r = e[p]
                lines.append(f"| {p} | {_f(r['success_rate_on_feasible'] * 100, '{:.1f}%')} | "
                             f"{_f(r['mean_gap_removals'])} | {_f(None if r['optimal_rate'] is None else r['optimal_rate'] * 100, '{:.1f}%')} "
                             f"| {r.get('infeasible_flagged', 0)}/{r.get('infeasible_tasks', 0)} |")
    nt = summary.get("no_truth") or {}
    if nt.get("tasks"):
        lines += ["", f"Not judged: {nt['tasks']} tasks on {len(nt['scenes'])} scenes that stand under no truth "
                  f"draw ({', '.join(nt['scenes'][:8])}{' ...' if len(nt['scenes']) > 8 else ''})."]
    run = summary.get("run")
    if run:
        lines += ["", f"Run: {run['mode']}, {run['new_tasks']} new tasks in {run['wall_s']} s "
                  f"({_f(run['throughput_tasks_per_s'], '{:.3f}')} tasks/s); {run['tasks']} tasks in total."]
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: str | Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = summary["table"]
    kinds = list(table)
    planners = summary["config"]["planners"]
    fig, axes = plt.subplots(1, 3, figsize=(13, 4))
    metrics = [("success_rate", "success rate", 100.0), ("mean_removed", "boxes removed", 1.0),
               ("plan_p50_s", "planning time p50 (s)", 1.0)]
    width = 0.8 / max(1, len(planners))
    for ax, (key, label, scale) in zip(axes, metrics):
        for i, p in enumerate(planners):
            vals = [(table[k].get(p, {}).get(key) or 0.0) * scale for k in kinds]
            xs = [j + (i - (len(planners) - 1) / 2) * width for j in range(len(kinds))]
            ax.bar(xs, vals, width, label=p)
        ax.set_xticks(range(len(kinds)), kinds)
        ax.set_title(label)
    axes[0].set_ylim(0, 100)
    axes[0].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def write_reports(out: Path, summary: dict) -> None:

    write_json(out / "results.json", summary)
    (out / "results.md").write_text(to_markdown(summary), encoding="utf-8")
    plot(summary, out / "results.png")


def comparable(records: Iterable[dict]) -> list[dict]:
    """Records without the machine's timings, sorted by key: equal for serial, workers and Ray."""
    def strip(r: dict) -> dict:
        r = {k: v for k, v in r.items() if k not in TIMING_KEYS}
        r["planners"] = {p: {k: v for k, v in d.items() if k not in TIMING_KEYS}
                         for p, d in r.get("planners", {}).items()}
        return r
    return sorted((strip(r) for r in records), key=lambda r: r["key"])
