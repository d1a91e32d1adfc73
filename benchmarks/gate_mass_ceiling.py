"""How much of a plan's fate is the masses nobody sees? The judge's own verdict over mass draws.

A diagnostic of the gate's target (issue 32), not a planner: for each plan of a judge run
(`../shared/judge/evaluate.py --out ROWS`), the plan is judged again by the independent judge
(imported at run time from its folder, never copied) on the TRUE shelf, its geometry exact, with
the boxes' masses drawn again `--draws` times (seeded, uniform in `--mass`, the range the judge's
generator documents). The share of draws in which the plan fails is its chance of failing on a
shelf that looks exactly like this one: what a gate that knew the geometry perfectly, and only not
the masses, should report. If most plans that held on the judge's one draw of masses fail in more
than `--max-risk` of the draws, no honest gate can declare most holding plans safe.

    .venv/bin/python benchmarks/gate_mass_ceiling.py --rows rows_0.jsonl --draws 16 --out ceiling.jsonl
"""
from __future__ import annotations

import argparse
import json
import random
import sys
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import UsageError, iter_rows, judge_fn  # noqa: E402
from shelfpick.planning.calibration import wilson  # noqa: E402


def redraw_masses(truth: dict, seed: int, draw: int, mass: tuple[float, float]) -> dict:
    """The true shelf with every box's mass drawn again (uniform in `mass`), geometry untouched."""
    rng = random.Random(f"gate-mass-ceiling:{seed}:{draw}")
    boxes = [{**b, "mass": round(rng.uniform(*mass), 4)} for b in truth["boxes"]]
    return {**truth, "boxes": boxes}


def judge_unit(unit: dict) -> dict:
    """One plan judged under every mass draw: the row with `fails` of `draws`."""
    judge = judge_fn(unit["engine"])
    truth = json.loads(Path(unit["judge_dir"], "scenes", unit["scene"] + ".json").read_text())
    plan = {"format": "shelfpick.plan/1", "task": "extract", "target": unit["target"],
            "planner": "physics", "sequence": unit["sequence"]}
    fails = sum(not judge(redraw_masses(truth, unit["seed"], d, unit["mass"]), plan)["ok"]
                for d in range(unit["draws"]))
    keep = ("scene", "target", "ok", "declared_safe", "risk", "sequence")
    return {**{k: unit[k] for k in keep}, "fails": fails, "draws": unit["draws"]}


def summary(rows: Sequence[dict], max_risk: float, z: float = 1.2816) -> dict:
    """How many plans are safe on their geometry (Wilson upper end of fails/draws below
    `max_risk`), and how the judge's one draw and our gate fare against that."""
    def low_risk(r: dict) -> bool:       # the share itself: a point estimate, not a bound
        return r["fails"] <= max_risk * r["draws"]

    def surely_low(r: dict) -> bool:     # the share's Wilson upper end below `max_risk`
        return wilson(r["fails"], r["draws"], z)[1] < max_risk

    held = [r for r in rows if r["ok"]]
    return {"plans": len(rows), "held": len(held),
            "held_low_risk": sum(low_risk(r) for r in held),
            "held_surely_low_risk": sum(surely_low(r) for r in held),
            "held_no_failing_draw": sum(r["fails"] == 0 for r in held),
            "low_risk": sum(low_risk(r) for r in rows),
            "low_risk_failed_on_judge": sum(low_risk(r) and not r["ok"] for r in rows),
            "declared_safe": sum(bool(r["declared_safe"]) for r in rows),
            "declared_safe_failing_in_a_fifth_or_more": sum(bool(r["declared_safe"]) and r["fails"] >= 0.2 * r["draws"]
                                                             for r in rows),
            "mean_fail_share_held": round(sum(r["fails"] / r["draws"] for r in held) / max(1, len(held)), 3)}


def expected_auc(risks: Sequence[float], shares: Sequence[float]) -> float:
    """The AUC a risk scores in expectation over the masses, each plan failing with its share p of
    failing draws: over pairs of plans, the chance that the one that collapses carries more risk."""
    num = den = 0.0
    for i, (ri, pi) in enumerate(zip(risks, shares)):
        for j, (rj, pj) in enumerate(zip(risks, shares)):
            if i != j:
                w = pi * (1 - pj)
                den += w
                num += w * (1.0 if ri > rj else 0.5 if ri == rj else 0.0)
    return round(num / den, 3) if den else float("nan")


def expected_sides(rows: Sequence[dict], max_rate: float) -> dict:
    """The issue's two gate figures in expectation over the masses, each plan failing with its share
    p of failing draws: the share of "safe" plans that collapse is their mean p, the share of
    holding plans declared safe is the sum of (1 - p) over "safe" plans over that sum over all.
    The oracle knows every p and calls safe the lowest-p plans while their mean p stays within
    `max_rate` (an aggregate bound, as the issue states its target, not a bound on each plan);
    "ours" is the gate of the judge run the rows carry (`declared_safe`)."""
    ps = sorted(r["fails"] / r["draws"] for r in rows)
    hold = sum(1 - p for p in ps) or float("nan")
    k, total = 0, 0.0
    while k < len(ps) and total + ps[k] <= max_rate * (k + 1):
        total += ps[k]
        k += 1
    ours = [r["fails"] / r["draws"] for r in rows if r["declared_safe"]]
    risks = [r["risk"] for r in rows if r.get("risk") is not None]
    floor = [r["fails"] / r["draws"] for r in rows if risks and r.get("risk") == min(risks)]
    return {"expected_holding": round(hold, 1),
            "oracle_safe": k, "oracle_collapse_share": round(sum(ps[:k]) / k, 3) if k else float("nan"),
            "oracle_held_safe_share": round(sum(1 - p for p in ps[:k]) / hold, 3),
            "oracle_largest_share": ps[k - 1] if k else float("nan"),
            "ours_held_safe_share": round(sum(1 - p for p in ours) / hold, 3),
            "ours_expected_auc": expected_auc(risks, [r["fails"] / r["draws"] for r in rows if r.get("risk") is not None]),
            # the plans at our risk's lowest value (the map's floor): their mean share of failing draws
            "floor_plans": len(floor), "floor_mean_share": round(sum(floor) / len(floor), 3) if floor else float("nan")}


def regate(ceiling: Sequence[dict], rows_path: str, verdicts: bool = True) -> list[dict]:
    """The ceiling rows of the plans another judge run has, with its verdicts (declared_safe, risk
    and ok; with `verdicts` False, the rows' own: only the plans are taken, to compare two runs over
    the tasks a shorter one reached); a UsageError when a plan's sequence differs (then its mass
    draws are not its own)."""
    try:
        rows = {(r["scene"], r["target"]): r for r in map(json.loads, Path(rows_path).read_text().splitlines())}
    except (OSError, json.JSONDecodeError, KeyError) as exc:
        raise UsageError(f"{rows_path}: cannot read judge rows ({exc})") from None
    out = []
    for c in ceiling:
        r = rows.get((c["scene"], c["target"]))
        if r is None:
            continue
        if r.get("sequence") != c["sequence"]:
            raise UsageError(f"{rows_path}: {c['scene']}:{c['target']} was planned differently; judge its plans again")
        out.append({**c, "declared_safe": r["declared_safe"], "risk": r.get("risk"), "ok": r["ok"]} if verdicts else c)
    return out


def gate_auc(rows: Sequence[dict], max_risk: float) -> float:
    """AUC of the plans' risk against "fails in more than `max_risk` of the mass draws": the ranking
    judged on each plan's chance rather than on the judge's one draw."""
    pos = [r["risk"] for r in rows if r.get("risk") is not None and r["fails"] > max_risk * r["draws"]]
    neg = [r["risk"] for r in rows if r.get("risk") is not None and r["fails"] <= max_risk * r["draws"]]
    if not pos or not neg:
        return float("nan")
    return round(sum((p > n) + 0.5 * (p == n) for p in pos for n in neg) / (len(pos) * len(neg)), 3)


def noise_floor(rows: Sequence[dict], reps: int = 500, seed: int = 0) -> dict:
    """What the judge's one draw of masses allows the risk figures: AUC and calibration error of the
    ideal risk (each plan's share of failing mass draws) against the judge's verdict, and the
    calibration error a perfectly calibrated risk would show on these plans by chance alone (each
    plan's verdict drawn `reps` times with its share as the chance: mean, 5th and 95th percentile)."""
    from benchmarks.risk_gate_report import auc, calibration_error

    ideal = [{"risk": r["fails"] / r["draws"], "ok": r["ok"]} for r in rows]
    rng = random.Random(f"gate-mass-ceiling-floor:{seed}")
    es = sorted(calibration_error([{"risk": r["risk"], "ok": rng.random() >= r["risk"]} for r in ideal])[0]
                for _ in range(reps))
    return {"ideal_auc": round(auc(ideal), 3), "ideal_calibration_error": round(calibration_error(ideal)[0], 3),
            "calibrated_error_by_chance": [round(es[len(es) // 2], 3), round(es[len(es) // 20], 3),
                                           round(es[len(es) * 19 // 20], 3)]}


def plot(rows: Sequence[dict], path: str, max_risk: float) -> None:
    """Each plan's share of failing mass draws, by what the gate said and what the judge saw."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    groups = [("declared safe, held", True, True, "tab:green"), ("declared safe, collapsed", True, False, "tab:red"),
              ("not safe, held", False, True, "tab:olive"), ("not safe, collapsed", False, False, "tab:gray")]
    fig, ax = plt.subplots(figsize=(7, 3.6))
    for i, (label, safe, ok, colour) in enumerate(groups):
        ys = sorted(r["fails"] / r["draws"] for r in rows if bool(r["declared_safe"]) == safe and r["ok"] == ok)
        xs = [i + (j - len(ys) / 2) / max(1, len(ys)) * 0.7 for j in range(len(ys))]
        ax.scatter(xs, ys, s=12, color=colour)
    ax.axhline(max_risk, color="k", lw=0.8, ls="--")
    ax.set_xticks(range(len(groups)), [f"{g[0]}\n({sum(1 for r in rows if bool(r['declared_safe']) == g[1] and r['ok'] == g[2])})"
                                       for g in groups], fontsize=8)
    ax.set_ylabel("share of mass draws that fail\n(judge, true geometry)")
    ax.set_title("Each plan on its true shelf, masses drawn again", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", help="rows of ../shared/judge/evaluate.py --out")
    ap.add_argument("--judge", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--engine", default="pybullet", choices=("pybullet", "mujoco"))
    ap.add_argument("--draws", type=int, default=16)
    ap.add_argument("--mass", type=float, nargs=2, default=(0.5, 3.0), metavar=("LOW", "HIGH"))
    ap.add_argument("--max-risk", type=float, default=0.05)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", help="write one row per plan here (JSON lines)")
    ap.add_argument("--from-rows", action="store_true", help="judge nothing: summarize the rows in --out")
    ap.add_argument("--png", help="draw each plan's failing share by gate verdict and judge outcome")
    ap.add_argument("--plans-of", help="with --from-rows: only the plans this judge run has (verdicts kept)")
    ap.add_argument("--gate-rows", help="with --from-rows: score the gate of this judge run (same plans, e.g. a "
                                        "later run whose sequences are the same) against the mass draws in --out")
    a = ap.parse_args(argv)
    if not a.rows and not a.from_rows:
        raise UsageError("--rows: the judge rows to judge again are needed (or --from-rows)")
    if a.draws < 1:
        raise UsageError(f"--draws: expected a positive number, got {a.draws}")
    if not 0 < a.mass[0] <= a.mass[1]:
        raise UsageError(f"--mass: expected 0 < LOW <= HIGH, got {a.mass[0]} {a.mass[1]}")
    return a


def main(argv: Sequence[str] | None = None) -> int:
    try:
        a = parse_args(argv)
        if a.from_rows:
            if not a.out:
                raise UsageError("--from-rows: needs --out, the rows to summarize")
            got = [json.loads(line) for line in Path(a.out).read_text().splitlines() if line.strip()]
            if a.plans_of:
                got = regate(got, a.plans_of, verdicts=False)
            if a.gate_rows:
                got = regate(got, a.gate_rows)
            return report(got, a)
        src = Path(a.rows)
        try:
            rows = [json.loads(line) for line in src.read_text().splitlines() if line.strip()]
        except (OSError, json.JSONDecodeError) as exc:
            raise UsageError(f"{src}: cannot read judge rows ({exc})") from None
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    units = [{**r, "judge_dir": a.judge, "engine": a.engine, "draws": a.draws, "mass": tuple(a.mass),
              "seed": a.seed} for r in rows if r.get("sequence")]
    out = open(a.out, "w") if a.out else None
    got = []
    from tqdm import tqdm
    for row in tqdm(iter_rows(units, a.jobs, judge_unit), total=len(units), desc="plans", file=sys.stderr):
        got.append(row)
        if out:
            out.write(json.dumps(row) + "\n")
            out.flush()
    return report(got, a)


def report(got: Sequence[dict], a: argparse.Namespace) -> int:
    """Print the summary (and draw it with --png)."""
    s = summary(got, a.max_risk)
    if got:
        s.update(noise_floor(got))
        safe = [r["fails"] / r["draws"] for r in got if r["declared_safe"]]
        s["declared_safe_mean_fail_share"] = round(sum(safe) / len(safe), 3) if safe else float("nan")
        s["declared_safe_low_risk_held"] = sum(1 for r in got if r["declared_safe"] and r["ok"] and r["fails"] <= a.max_risk * r["draws"])
        s["gate_auc_on_mass_draws"] = gate_auc(got, a.max_risk)
        s.update(expected_sides(got, a.max_risk))
    if a.png:
        plot(got, a.png, a.max_risk)
    print(json.dumps(s))
    print(f"{s['held']} plans held on the judge's masses; on their true geometry {s['held_low_risk']} of them "
          f"fail in at most {a.max_risk:.0%} of {got[0]['draws'] if got else a.draws} mass draws ({s['held_surely_low_risk']} surely: "
          f"Wilson upper end below it), "
          f"{s['held_no_failing_draw']} in none; mean fail share of held plans {s['mean_fail_share_held']}")
    if got:
        print(f"declared safe {s['declared_safe']}: mean share of failing mass draws {s['declared_safe_mean_fail_share']}, "
              f"{s['declared_safe_failing_in_a_fifth_or_more']} fail in a fifth or more; of the {s['held_low_risk']} "
              f"held plans failing in at most {a.max_risk:.0%}, {s['declared_safe_low_risk_held']} declared safe; "
              f"risk AUC against failing in more than {a.max_risk:.0%} of the draws {s['gate_auc_on_mass_draws']}")
        med, p5, p95 = s["calibrated_error_by_chance"]
        print(f"the ideal risk (share of failing mass draws): AUC {s['ideal_auc']}, calibration error "
              f"{s['ideal_calibration_error']}; a perfectly calibrated risk on these {len(got)} plans shows a "
              f"calibration error of {med} by chance alone (5-95%: {p5}-{p95})")
        print(f"in expectation over the masses: a gate that knew each plan's share calls {s['oracle_safe']} safe, "
              f"{s['oracle_collapse_share']:.1%} of them collapse, {s['oracle_held_safe_share']:.1%} of holding plans "
              f"declared safe (the largest share among them {s['oracle_largest_share']:.0%}); this run's gate: "
              f"{s['declared_safe_mean_fail_share']:.1%} and {s['ours_held_safe_share']:.1%}, its risk's expected AUC "
              f"{s['ours_expected_auc']}; the {s['floor_plans']} plans at its lowest risk fail in "
              f"{s['floor_mean_share']:.1%} of the draws")
    return 0


if __name__ == "__main__":
    sys.exit(main())
