"""Fit the risk calibration on the rows of `risk_calibration.py collect` (our own bench only).

A plan's example is (k, n, stands, failed on the truth): k the worlds of the first n in which some
step of the plan failed (a collapse, or a box that would not come out: `planning.gate.world_failed`),
`stands` whether the seen shelf stands in the sample worlds, and the truth's verdict (a collapse at
any step, or the target not out). Two kinds of plans: every box pulled alone from the full shelf (a
plan of one step), and the physics planner's plans. Each plan counts once at n = 10, 20 and 30 (the
prefixes of its worlds): the gate asks 10 to 40.

The shelves are split by seed: the map is fitted on the even seeds and its reliability measured on
the odd ones (held out), then refitted on all of them for the map shipped.
"""
from __future__ import annotations

import json
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any, Iterable, Sequence

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from shelfpick.planning.calibration import Calibration, fit  # noqa: E402

PREFIXES = (10, 20, 30)
BINS = (0.0, 0.02, 0.05, 0.1, 0.2, 0.4, 0.7, 1.0001)


def _fails(row: dict, collisions: bool = False) -> list[int]:
    """Per world: did this step fail (a collapse or a stuck box; with `collisions`, also a neighbour
    the box or the gripper touched that then moved)."""
    xs = row["x"] if collisions else [0] * len(row["c"])
    return [int(c or s or x) for c, s, x in zip(row["c"], row["s"], xs)]


def plans(rows: Iterable[dict], collisions: bool = False) -> list[dict]:
    """One record per plan: per-world failure flags (union over its steps), stands, truth failed."""
    out = []
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in rows:
        if r["source"] == "alone":
            out.append({"scene": r["scene"], "noise": r["noise"], "kind": r["kind"], "source": "alone",
                        "truth_pull": r.get("truth_pull", "drag"),
                        "fails": _fails(r, collisions), "stands": r["stands"],
                        "failed": bool(r["collapse"] or not r["extracted"]), "steps": 1})
        else:
            groups[(r["scene"], r["noise"], r["target"], r.get("truth_pull", "drag"))].append(r)
    for (scene, noise, _, pull), steps in groups.items():
        steps.sort(key=lambda r: r["step"])
        per = [_fails(r, collisions) for r in steps]
        union = [int(any(f[i] for f in per)) for i in range(min(len(f) for f in per))]
        failed = not steps[0]["plan_ok"]
        out.append({"scene": scene, "noise": noise, "kind": steps[0]["kind"], "source": "plan", "fails": union,
                    "truth_pull": pull,
                    "stands": steps[0]["stands"], "failed": failed, "steps": len(steps)})
    return out


def examples(ps: Sequence[dict], prefixes: Sequence[int] = PREFIXES) -> list[tuple[int, int, bool, bool]]:
    return [(sum(p["fails"][:n]), n, p["stands"], p["failed"]) for p in ps for n in prefixes if len(p["fails"]) >= n]


def plan_of(ps: Sequence[dict], prefixes: Sequence[int] = PREFIXES) -> list[int]:
    """Which plan each row of `examples(ps, prefixes)` comes from (the fit's floor counts a plan once)."""
    return [i for i, p in enumerate(ps) for n in prefixes if len(p["fails"]) >= n]


def _seed(p: dict) -> int:
    return int(p["scene"].rsplit("-", 1)[1])


def reliability(cal: Calibration, ex: Sequence[tuple[int, int, bool, bool]]) -> dict[str, Any]:
    """Binned predicted probability against the observed failure rate; ECE (count-weighted |gap|)."""
    bins: list[list[tuple[float, bool]]] = [[] for _ in range(len(BINS) - 1)]
    for k, n, st, y in ex:
        p = cal.probability(k, n, st)
        for i in range(len(BINS) - 1):
            if BINS[i] <= p < BINS[i + 1]:
                bins[i].append((p, y))
                break
    table, ece, total = [], 0.0, len(ex)
    for i, b in enumerate(bins):
        if not b:
            continue
        mp = sum(p for p, _ in b) / len(b)
        obs = sum(y for _, y in b) / len(b)
        table.append({"bin": f"[{BINS[i]:.2f}, {min(BINS[i + 1], 1):.2f})", "count": len(b),
                      "mean_predicted": round(mp, 4), "observed": round(obs, 4), "failed": sum(y for _, y in b)})
        ece += len(b) / total * abs(mp - obs)
    return {"table": table, "ece": round(ece, 4), "n": total}


def gate_safe(cal: Calibration, p: dict, threshold: float, max_worlds: int = 30) -> bool:
    """Whether the gate calls a stored plan safe, asking its worlds as `planning.gate` does (10, then
    10 more while the calibrated interval is undecided, up to `max_worlds`)."""
    n = 10
    while True:
        k = sum(p["fails"][:n])
        if n >= max_worlds or cal.decided(k, n, threshold, p["stands"]):
            break
        n += 10
    return cal.interval(k, n, p["stands"])[1] < threshold


def gate_figures(cal: Calibration, ps: Sequence[dict], threshold: float, max_worlds: int = 30) -> dict[str, Any]:
    """The gate on these plans as `planning.gate` runs it (10 worlds, +10 while undecided)."""
    said_safe = held = held_safe = safe_failed = 0
    for p in ps:
        safe = gate_safe(cal, p, threshold, max_worlds)
        said_safe += safe
        held += not p["failed"]
        held_safe += safe and not p["failed"]
        safe_failed += safe and p["failed"]
    return {"plans": len(ps), "held": held, "declared_safe": said_safe, "held_declared_safe": held_safe,
            "safe_failed": safe_failed}


def _plot(path: str, panels: list[tuple[str, dict]]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 4.0))
    for ax, (title, rel) in zip(axes if len(panels) > 1 else [axes], panels):
        xs = [r["mean_predicted"] for r in rel["table"]]
        ys = [r["observed"] for r in rel["table"]]
        ax.plot([0, 1], [0, 1], color="0.7", lw=1)
        ax.scatter(xs, ys, s=[12 + 2 * r["count"] for r in rel["table"]], color="tab:blue", zorder=3)
        for r in rel["table"]:
            ax.annotate(str(r["count"]), (r["mean_predicted"], r["observed"]), fontsize=7,
                        xytext=(4, -8), textcoords="offset points")
        ax.set_xlim(-0.02, 1.02)
        ax.set_ylim(-0.02, 1.02)
        ax.set_xlabel("calibrated probability of a collapse")
        ax.set_ylabel("observed on the bench's truth")
        ax.set_title(f"{title}\nECE {rel['ece']:.3f}, {rel['n']} plan-worlds", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def run_fit(rows_path: str, json_out: str | None, png: str | None, md: str | None,
            collisions: bool = False) -> int:
    rows = [json.loads(line) for p in rows_path.split(",") for line in Path(p).read_text().splitlines()
            if line.strip()]
    ps = plans(rows, collisions)
    pulls = {p["truth_pull"] for p in ps}
    if len(pulls) > 1:   # a mixture of truths: only the shelf views every truth was run on, each once per truth
        views = [{(p["scene"], p["noise"]) for p in ps if p["truth_pull"] == t} for t in sorted(pulls)]
        both = set.intersection(*views)
        ps = [p for p in ps if (p["scene"], p["noise"]) in both]
    even = [p for p in ps if _seed(p) % 2 == 0]
    odd = [p for p in ps if _seed(p) % 2 == 1]
    if not even or not odd:
        raise SystemExit("risk_fit: the rows need shelves of even and of odd seeds (collect --scenes 2 or more)")
    half = fit(examples(even), fitted_on="even seeds", groups=plan_of(even))
    cal = fit(examples(ps), groups=plan_of(ps), fitted_on=f"{rows_path}: {len(ps)} plans on "
                                      f"{len({(p['scene'], p['noise']) for p in ps})} shelf views")
    raw = Calibration(0.0, 1.0, 0.0, floor=1e-6, fitted_on="identity: the share of failing worlds")
    rel_raw = reliability(raw, examples(odd, (10,)))
    rel_held = reliability(half, examples(odd))
    rel_all = reliability(cal, examples(ps))
    doc = {"calibration": cal.to_json(), "held_out": {"fit_on_even": half.to_json(), "odd": rel_held},
           "uncalibrated_share_odd_10_worlds": rel_raw, "all": rel_all,
           "gate_0.05": {"held_out": gate_figures(half, odd, 0.05), "all": gate_figures(cal, ps, 0.05)},
           "plans": len(ps), "failed": sum(p["failed"] for p in ps)}
    text = json.dumps(doc, indent=1)
    print(text)
    if json_out:
        Path(json_out).write_text(text + "\n")
    if png:
        _plot(png, [("share of failing worlds (10), held-out seeds", rel_raw),
                    ("calibrated, fitted on even seeds, held-out odd", rel_held),
                    ("calibrated, fitted on all", rel_all)])
    if md:
        Path(md).write_text(_markdown(doc, rows_path))
    return 0


def _markdown(doc: dict, rows_path: str) -> str:
    c = doc["calibration"]
    out = [f"Fitted on `{rows_path}` (`benchmarks/risk_calibration.py fit`): {doc['plans']} plans, "
           f"{doc['failed']} failed on the truth.", "",
           f"p = sigmoid({c['intercept']:.3f} + {c['slope']:.3f} * logit(share) + {c['not_standing']:.3f} * not standing)",
           ""]
    for name, rel in (("uncalibrated share, 10 worlds, odd seeds", doc["uncalibrated_share_odd_10_worlds"]),
                      ("fitted on even seeds, odd seeds held out", doc["held_out"]["odd"]),
                      ("fitted on all", doc["all"])):
        out += [f"**{name}** (ECE {rel['ece']:.3f}, {rel['n']} plan-worlds)", "",
                "| calibrated probability | plan-worlds | mean predicted | failed | observed |", "|---|---:|---:|---:|---:|"]
        out += [f"| {r['bin']} | {r['count']} | {r['mean_predicted']:.3f} | {r['failed']} | {r['observed']:.3f} |"
                for r in rel["table"]]
        out.append("")
    for name, g in doc["gate_0.05"].items():
        out.append(f"Gate at 0.05 ({name}): {g['plans']} plans, {g['held']} held; declared safe {g['declared_safe']}, "
                   f"of which failed {g['safe_failed']}; held and declared safe {g['held_declared_safe']}/{g['held']}.")
    return "\n".join(out) + "\n"


if __name__ == "__main__":
    raise SystemExit(run_fit(*(sys.argv[1:2] + [None, None, None])))
