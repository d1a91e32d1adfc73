"""The judge report's arithmetic on rows: evaluate.py's figures per noise, planner and engine, plan-time
percentiles, engine agreement, and the reliability table (predicted risk vs the judge's collapses).

Plain data in, plain data out: the markdown and the plot are drawn from what `summarize` returns.
"""
from __future__ import annotations

from typing import Any, Iterable, Iterator, Sequence

ENGINES = ("pybullet", "mujoco")
# predicted-risk bins of the reliability table: exactly 0, then (lo, hi]
RISK_BINS: tuple[tuple[float, float], ...] = ((0.0, 0.0), (0.0, 0.05), (0.05, 0.1), (0.1, 0.2),
                                              (0.2, 0.4), (0.4, 1.0))


def percentile(values: Sequence[float], q: float) -> float:
    """Linear-interpolated percentile, nan for no values."""
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
    """A risk bin as the table prints it: 0 or (lo, hi]."""
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
    """Rows by (noise, planner), in report order."""
    out: dict[tuple[float, str], list[dict]] = {}
    for r in sorted(rows, key=lambda r: (r["noise"], r["planner"], r["scene"], r["target"] or "")):
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
