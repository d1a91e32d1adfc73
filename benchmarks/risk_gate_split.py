"""Both sides of the gate on a held-out split of our own calibration bench (issue 32; never the judge).

    .venv/bin/python benchmarks/risk_gate_split.py NAME=ROWS.jsonl[+ROWS.jsonl] [NAME=...] \
        [--held-out 12] [--label end|ours] [--source all|plan|alone] [--md OUT.md]

ROWS are `benchmarks/risk_calibration.py collect` lines; files joined with `+` are one bench (a
mixture of truths: the same shelves with a dragging and a lifting truth, each plan once per truth). Per file: the map (`planning.calibration.fit`)
is fitted on the shelves whose seed is not in `--held-out`, and the gate is run on the held-out ones
as `planning.gate` runs it (10 worlds, then 10 more while the interval straddles 0.05, up to 30; a
shelf that does not stand as seen in the planner's 10 worlds is never safe). The truth's verdict
(`--label`): `end`, a box that ends past the end-of-step thresholds or a box not out (the same for
every physics of the worlds, since the truth's own verdict is not read); `ours`, the truth run's own
collapse verdict. Figures: plans, held, held plans declared safe, declared-safe plans that failed,
AUC of the calibrated probability at 30 worlds, calibration error (count-weighted |predicted -
observed| over the bins of `risk_fit.BINS`).
"""
from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any, Sequence

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.risk_fit import BINS, gate_safe  # noqa: E402
from shelfpick.planning.calibration import Calibration, fit  # noqa: E402


def _fails(r: dict) -> list[int]:
    return [int(c or s) for c, s in zip(r["c"], r["s"])]


def _failed(steps: Sequence[dict], label: str) -> bool:
    if label == "ours":
        return not steps[0]["plan_ok"] if steps[0]["source"] == "plan" else bool(steps[0]["collapse"] or not steps[0]["extracted"])
    return any(s["end_collapse"] or not s["extracted"] for s in steps)


def plans(rows: Sequence[dict], label: str) -> list[dict]:
    """One record per plan (a box alone, or the planner's plan): per-world failures, stands, truth."""
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for i, r in enumerate(rows):
        pull = r.get("truth_pull", "drag")
        key = (r["scene"], r["noise"], "alone", r["box"], pull, i) if r["source"] == "alone" else \
            (r["scene"], r["noise"], "plan", r["target"], pull, 0)
        groups[key].append(r)
    out = []
    for (scene, noise, source, _, pull, _), steps in groups.items():
        steps.sort(key=lambda r: r.get("step", 0))
        per = [_fails(r) for r in steps]
        n = min(len(f) for f in per)
        out.append({"scene": scene, "noise": noise, "source": source, "seed": int(scene.rsplit("-", 1)[1]), "truth": pull,
                    "fails": [int(any(f[i] for f in per)) for i in range(n)],
                    "stands": steps[0]["stands"], "stands10": steps[0].get("stands10", steps[0]["stands"]),
                    "failed": _failed(steps, label)})
    return out


def _examples(ps: Sequence[dict]) -> list[tuple[int, int, bool, bool]]:
    return [(sum(p["fails"][:n]), n, p["stands"], p["failed"]) for p in ps for n in (10, 20, 30)
            if len(p["fails"]) >= n]


def auc(scores: Sequence[float], labels: Sequence[bool]) -> float:
    """The chance that a failing plan scores above a holding one (ties count half)."""
    pos = [s for s, y in zip(scores, labels) if y]
    neg = [s for s, y in zip(scores, labels) if not y]
    if not pos or not neg:
        return float("nan")
    wins = sum((p > q) + 0.5 * (p == q) for p in pos for q in neg)
    return wins / (len(pos) * len(neg))


def ece(probs: Sequence[float], labels: Sequence[bool]) -> float:
    total, err = len(probs), 0.0
    for i in range(len(BINS) - 1):
        b = [(p, y) for p, y in zip(probs, labels) if BINS[i] <= p < BINS[i + 1]]
        if b:
            err += len(b) / total * abs(sum(p for p, _ in b) / len(b) - sum(y for _, y in b) / len(b))
    return err


def gate_side(cal: Calibration, ps: Sequence[dict], threshold: float = 0.05, max_worlds: int = 30) -> dict[str, Any]:
    safe_held = safe_failed = safe_n = held = 0
    for p in ps:
        safe = gate_safe(cal, p, threshold, max_worlds) and p["stands10"]
        held += not p["failed"]
        safe_n += safe
        safe_held += safe and not p["failed"]
        safe_failed += safe and p["failed"]
    return {"plans": len(ps), "held": held, "declared_safe": safe_n, "held_declared_safe": safe_held,
            "safe_failed": safe_failed}


def evaluate(rows: Sequence[dict], held_out: set[int], label: str, source: str = "all") -> dict[str, Any]:
    """The map fitted on every plan of the shelves not held out; the figures on the held-out plans
    of `source` (all, the planner's `plan`s, or boxes pulled `alone`)."""
    ps = plans(rows, label)
    train = [p for p in ps if p["seed"] not in held_out]
    test = [p for p in ps if p["seed"] in held_out and source in ("all", p["source"])]
    cal = fit(_examples(train), fitted_on="seeds not held out")
    probs = [cal.probability(sum(p["fails"][:30]), min(30, len(p["fails"])), p["stands"]) for p in test]
    ys = [p["failed"] for p in test]
    g = gate_side(cal, test)
    return dict(g, auc=auc(probs, ys), auc_share=auc([sum(p["fails"][:30]) for p in test], ys),
                ece=ece(probs, ys), calibration=cal.to_json(), train_plans=len(train))


def _pct(a: int, b: int) -> str:
    return f"{a}/{b} ({100 * a / b:.0f} %)" if b else f"{a}/0"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="NAME=ROWS.jsonl")
    ap.add_argument("--held-out", default="12", help="comma-separated shelf seeds held out")
    ap.add_argument("--label", choices=("end", "ours"), default="end")
    ap.add_argument("--source", choices=("all", "plan", "alone"), default="all",
                    help="which held-out plans the figures are over (the map is fitted on all)")
    ap.add_argument("--md")
    a = ap.parse_args(argv)
    held_out = {int(s) for s in a.held_out.split(",")}
    lines = ["| worlds' physics | held-out plans | held | held plans declared safe | declared safe that failed "
             "| AUC | calibration error |", "|---|---:|---:|---:|---:|---:|---:|"]
    for run in a.runs:
        name, path = run.split("=", 1)
        rows = [json.loads(x) for p in path.split("+") for x in Path(p).read_text().splitlines() if x.strip()]
        r = evaluate(rows, held_out, a.label, a.source)
        print(json.dumps({name: r}), flush=True)
        lines.append(f"| {name} | {r['plans']} | {r['held']} | {_pct(r['held_declared_safe'], r['held'])} | "
                     f"{_pct(r['safe_failed'], r['declared_safe'])} | {r['auc']:.3f} | {r['ece']:.3f} |")
    text = "\n".join(lines) + "\n"
    print(text)
    if a.md:
        Path(a.md).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
