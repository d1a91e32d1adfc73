"""The judge report as markdown: evaluate.py's summary lines, a table per (noise, planner, engine),
plans that hold in only one engine, and the reliability tables, all drawn from `summarize`'s data."""
from __future__ import annotations

from benchmarks.judge_summary import evaluate_line


def _pct(k: int, n: int) -> str:
    return f"{k}/{n} ({100 * k / n:.0f}%)" if n else f"{k}/0"


def _f(x: float, fmt: str = "{:.2f}") -> str:
    return "-" if x != x else fmt.format(x)


def _group_table(summary: dict) -> list[str]:
    lines = ["", "| noise | planner | engine | ok | structured | unstructured | solvable ok | removed vs min "
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
    return lines


def _agreement_table(summary: dict) -> list[str]:
    agree = [g for g in summary["groups"] if "agreement" in g]
    if not agree:
        return []
    lines = ["", "Plans that hold in only one engine (the same plan judged by both):", "",
             "| noise | planner | plans | ok in pybullet only | ok in mujoco only |", "|---|---|---|---|---|"]
    for g in agree:
        a = g["agreement"]
        lines.append(f"| {g['noise']:g} | {g['planner']} | {a['plans']} | {a['pybullet_only']} "
                     f"| {a['mujoco_only']} |")
    return lines


def _reliability_tables(summary: dict) -> list[str]:
    lines: list[str] = []
    for rel in summary["reliability"]:
        lines += ["", f"Reliability, noise {rel['noise']:g}, {rel['engine']} judge: every step up to and "
                  "including the judge's first collapse, by predicted risk", "",
                  "| predicted risk | steps (all planners) | mean predicted | collapses | observed "
                  "| physics steps | physics observed |", "|---|---|---|---|---|---|---|"]
        for a, p in zip(rel["all"], rel["physics"]):
            lines.append(f"| {a['bin']} | {a['steps']} | {_f(a['predicted'], '{:.3f}')} | {a['collapses']} "
                         f"| {_f(a['observed'], '{:.3f}')} | {p['steps']} | {_f(p['observed'], '{:.3f}')} |")
    return lines


def to_markdown(summary: dict, header: str = "") -> str:
    """The report: evaluate.py's lines, a table per group, engine agreement, reliability tables."""
    lines = [header, ""] if header else []
    for g in summary["groups"]:
        for e, s in g["engines"].items():
            lines.append("    " + evaluate_line(g["planner"], g["noise"], e, s))
    lines += _group_table(summary) + _agreement_table(summary) + _reliability_tables(summary)
    return "\n".join(lines) + "\n"
