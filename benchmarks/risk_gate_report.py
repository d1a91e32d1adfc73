"""The gate's figures from the rows `../shared/judge/evaluate.py --out ROWS` writes (issue 32).

    .venv/bin/python benchmarks/risk_gate_report.py LABEL=ROWS.jsonl [LABEL=ROWS.jsonl ...] [--md OUT.md]

Per run: ok, plans that held declared safe, plans declared safe that collapsed, the risk AUC (the
chance that a failing plan carries more risk than a holding one, ties half: evaluate.py's own
definition) and the calibration error: plans binned by predicted risk (1 - search.success_prob) in
tenths, |mean predicted - observed failure rate| weighted by the bin's share. The judge's rows are
read, never fitted on: the calibration is fitted on our own bench (benchmarks/risk_calibration.py).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any, Sequence


def auc(rows: Sequence[dict]) -> float:
    pos = [r["risk"] for r in rows if not r["ok"] and r.get("risk") is not None]
    neg = [r["risk"] for r in rows if r["ok"] and r.get("risk") is not None]
    if not pos or not neg:
        return float("nan")
    return sum((p > n) + 0.5 * (p == n) for p in pos for n in neg) / (len(pos) * len(neg))


def calibration_error(rows: Sequence[dict], bins: int = 10) -> tuple[float, list[dict[str, Any]]]:
    """Expected calibration error of the plans' risks against the judge's failures, and the table."""
    rs = [r for r in rows if r.get("risk") is not None]
    table = []
    ece = 0.0
    for i in range(bins):
        lo, hi = i / bins, (i + 1) / bins
        b = [r for r in rs if lo <= r["risk"] < hi or (i == bins - 1 and r["risk"] == 1.0)]
        if not b:
            continue
        mp = sum(r["risk"] for r in b) / len(b)
        obs = sum(not r["ok"] for r in b) / len(b)
        table.append({"bin": f"[{lo:.1f}, {hi:.1f})", "plans": len(b), "mean_risk": round(mp, 3),
                      "failed": sum(not r["ok"] for r in b), "observed": round(obs, 3)})
        ece += len(b) / len(rs) * abs(mp - obs)
    return ece, table


def as_evaluate_rows(rows: Sequence[dict], engine: str) -> list[dict]:
    """`judge_report.py` rows (one plan judged by several engines) as evaluate.py's rows for `engine`:
    ok, declared_safe, risk = 1 - success_prob (the same plans evaluate.py makes, docs/bench.md)."""
    out = []
    for r in rows:
        if "judges" not in r:
            out.append(r)
            continue
        v = r["judges"].get(engine)
        sp = r.get("success_prob")
        out.append({"scene": r["scene"], "target": r["target"], "ok": bool(v and v["ok"]),
                    "declared_safe": bool(r.get("declared_safe")) if v else False,
                    "risk": None if sp is None else round(1 - sp, 4)})
    return out


def figures(rows: Sequence[dict]) -> dict[str, Any]:
    ok = [r for r in rows if r["ok"]]
    safe = [r for r in rows if r.get("declared_safe")]
    ece, table = calibration_error(rows)
    return {"tasks": len(rows), "ok": len(ok), "held_declared_safe": sum(bool(r.get("declared_safe")) for r in ok),
            "declared_safe": len(safe), "safe_collapsed": sum(not r["ok"] for r in safe),
            "auc": round(auc(rows), 3), "ece": round(ece, 3), "table": table}


def read_rows(run: str, path: str) -> list[dict]:
    """The rows of one LABEL=ROWS argument; a ValueError naming the argument when it has no file,
    the file cannot be read, or a row is not JSON."""
    if not path:
        raise ValueError(f"{run!r}: expected LABEL=ROWS.jsonl")
    try:
        return [json.loads(x) for x in Path(path).read_text(encoding="utf-8").splitlines() if x.strip().startswith("{")]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"{path}: cannot read judge rows ({exc})") from None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="LABEL=ROWS.jsonl, or LABEL=ROWS.jsonl@ENGINE for judge_report.py rows")
    ap.add_argument("--md")
    a = ap.parse_args(argv)
    out = ["| run | ok | held, declared safe | declared safe, collapsed | risk AUC | calibration error |",
           "|---|---:|---:|---:|---:|---:|"]
    tables = []
    for run in a.runs:
        label, _, path = run.partition("=")
        path, _, engine = path.partition("@")
        try:
            rows = read_rows(run, path)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 2
        rows = as_evaluate_rows(rows, engine or "pybullet")
        f = figures(rows)
        held = f"{f['held_declared_safe']}/{f['ok']}" + (f" ({100 * f['held_declared_safe'] / f['ok']:.0f}%)" if f["ok"] else "")
        bad = f"{f['safe_collapsed']}/{f['declared_safe']}" + (
            f" ({100 * f['safe_collapsed'] / f['declared_safe']:.0f}%)" if f["declared_safe"] else "")
        out.append(f"| {label} | {f['ok']}/{f['tasks']} | {held} | {bad} | {f['auc']:.2f} | {f['ece']:.3f} |")
        tables += ["", f"{label}: plans by predicted risk", "", "| risk | plans | mean risk | failed | observed |",
                   "|---|---:|---:|---:|---:|"]
        tables += [f"| {t['bin']} | {t['plans']} | {t['mean_risk']:.3f} | {t['failed']} | {t['observed']:.3f} |"
                   for t in f["table"]]
    text = "\n".join(out + tables) + "\n"
    print(text)
    if a.md:
        Path(a.md).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
