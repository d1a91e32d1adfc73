"""Which unknown makes the sample worlds fail where a shelf holds? (issue 32, item 1)

A diagnostic of the gate's world model on OUR OWN shelves (`planning.shelves.generate`, seeds of
this script's own; never the judge's scenes). For each shelf, the physics planner's plan for a few
targets (made as `shelfpick plan` makes it, depths hidden) is asked three ways:

- **reference**: the independent judge's engine (../shared/judge, imported at run time, never
  copied) on the TRUE shelf, the boxes' masses drawn `--draws` times (uniform in `--mass`): the
  share of draws in which the plan fails. Both of the judge's engines with `--engines`.
- **pinned**: our sample-world physics on the same true shelf with the same masses, and every
  other unknown pinned to what the reference uses (friction 0.75, drag at 0.2 m/s with a 150 N
  limit, no face error): per draw, does our world agree with the reference?
- **ablations**: our sample worlds over `--draws` worlds, starting from the pinned model
  (geometry known, masses drawn by us in `--mass`) and widening one unknown at a time to the
  default cell's prior (friction, pull speed and force, masses, lift-or-drag, hidden depths,
  face error), then all of them (the default cell as shipped).

A row per plan (JSON lines, `--out`); the summary per condition: the mean share of failing worlds
over the plans that the reference holds in at most 5% of its draws ("quiet plans"), and over all.
An unknown whose widening raises the quiet plans' share a lot is where the gate's false alarms
come from; whether its range is plausible is then a question about the cell, not the threshold.

    .venv/bin/python benchmarks/world_ablation.py --kinds structured,unstructured --seeds 41000-41007 \
        --targets 2 --draws 20 --jobs 2 --out ablation.jsonl [--png ablation.png]
    .venv/bin/python benchmarks/world_ablation.py --from-rows --out ablation.jsonl
"""
from __future__ import annotations

import argparse
import json
import random
import sys
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import UsageError, iter_rows, judge_fn  # noqa: E402
from shelfpick.perception.errors import SceneError  # noqa: E402

# what the reference (the judge's README) pulls with, and its friction
REF = {"friction": 0.75, "pull_speed": 0.2, "pull_force": 150.0, "mode": "drag"}
DEFAULT_FRICTION = (0.6, 0.9)
SEARCH = "default cell, the search's own worlds (seed 0)"


def conditions(mass: tuple[float, float]) -> dict[str, dict]:
    """name -> (Uncertainty overrides, hide depths): the pinned model, then one unknown widened at a
    time to the default cell's prior, then the default cell itself."""
    from shelfpick.planning.uncertainty import Uncertainty

    d = Uncertainty()
    pinned = {"mass": tuple(mass), "friction": (REF["friction"],) * 2, "pull_speed": (REF["pull_speed"],) * 2,
              "pull_force": (REF["pull_force"],) * 2, "pull_modes": (REF["mode"],), "face_error": 0.0}
    return {
        "pinned physics, our masses": (pinned, False),
        "+ friction 0.6-0.9": ({**pinned, "friction": d.friction}, False),
        "+ pull 0.2-0.5 m/s, 100-200 N": ({**pinned, "pull_speed": d.pull_speed, "pull_force": d.pull_force}, False),
        "+ masses 0.3-5 kg log": ({**pinned, "mass": d.mass}, False),
        "+ lift or drag": ({**pinned, "pull_modes": d.pull_modes}, False),
        "+ depths hidden": (pinned, True),
        "+ depths hidden, face error 5 mm": ({**pinned, "face_error": d.face_error}, True),
        "default cell (all of them)": ({}, True),
    }


def contact_conditions(mass: tuple[float, float]) -> dict[str, tuple[dict, bool]]:
    """The friction read as a contact's (Bullet multiplies the two bodies' values): each body gets
    the square root, so two boxes touch with the value itself. Added with `--add contact`."""
    pinned, _ = conditions(mass)["pinned physics, our masses"]
    lo, hi = (f ** 0.5 for f in DEFAULT_FRICTION)
    return {"pinned, contact friction 0.75": ({**pinned, "friction": (0.75 ** 0.5,) * 2}, False),
            "+ contact friction 0.6-0.9": ({**pinned, "friction": (lo, hi)}, False)}


def mode_conditions() -> dict[str, tuple[dict, bool]]:
    """The default cell with its gripper's pull known: drag only, lift only (and as shipped, lift or
    drag), depths hidden, 20 worlds of the shelf's own seed (not the search's). Added with `--add modes`."""
    return {"default cell (all of them)": ({}, True), "default cell, drag only": ({"pull_modes": ("drag",)}, True),
            "default cell, lift only": ({"pull_modes": ("lift",)}, True)}


def drawn_masses(n: int, seed: int, draw: int, mass: tuple[float, float]) -> list[float]:
    rng = random.Random(f"world-ablation:{seed}:{draw}")
    return [round(rng.uniform(*mass), 4) for _ in range(n)]


def _fails_of(predictor, sequence: Sequence[str], worlds: int) -> list[bool]:
    """Per world: did some step of `sequence` fail (the gate's verdict per world)."""
    from shelfpick.planning.gate import world_failed

    runs = predictor.plan_results(sequence, worlds)
    n = min(len(r) for r in runs)
    return [any(world_failed(rs[i]) for rs in runs) for i in range(n)]


def masses_of(boxes: Sequence, seed: int, draw: int, mass: tuple[float, float]) -> list[float]:
    """The masses of draw `draw` for these boxes (the same for the reference and our pinned world)."""
    return drawn_masses(len(boxes), seed, draw, mass)


def reference_verdict(truth_json: dict, unit: dict, engine: str, draw: int) -> dict:
    """The judge's verdict (`engine`) on the plan of `unit` on the true shelf with draw `draw`'s masses."""
    plan = {"format": "shelfpick.plan/1", "task": "extract", "target": unit["target"],
            "planner": "physics", "sequence": unit["sequence"]}
    ms = masses_of(truth_json["boxes"], unit["seed"], draw, unit["mass"])
    return judge_fn(engine)({**truth_json, "boxes": [{**b, "mass": m} for b, m in zip(truth_json["boxes"], ms)]}, plan)


def reference_fails(truth_json: dict, unit: dict, engine: str, detail: list | None = None) -> list[bool]:
    """Per mass draw: did the plan fail on the reference? With `detail`, each failing draw's first
    failing step is appended to it (step index, the pulled box, the boxes that moved, an error)."""
    out = []
    for d in range(unit["draws"]):
        v = reference_verdict(truth_json, unit, engine, d)
        out.append(not v["ok"])
        if detail is not None and not v["ok"]:
            bad = [(i, e) for i, e in enumerate(v.get("steps", [])) if e.get("collapse") or e.get("error")]
            i, e = bad[0] if bad else (None, {})
            detail.append({"draw": d, "step": i, "pulled": e.get("id"), "moved": e.get("moved", []),
                           "error": e.get("error"), "max_disp": e.get("max_disp"), "max_rot_deg": e.get("max_rot_deg")})
    return out


def pinned_model():
    """Our worlds pinned to the reference: its friction and pull, no face error, the masses given."""
    from shelfpick.planning.uncertainty import Uncertainty

    return replace(Uncertainty(), mass=(0.0, 0.0), friction=(REF["friction"],) * 2,
                   pull_speed=(REF["pull_speed"],) * 2, pull_force=(REF["pull_force"],) * 2,
                   pull_modes=(REF["mode"],), face_error=0.0)


def pinned_fail(truth, unit: dict, draw: int, config=None) -> bool | None:
    """Our pinned world of draw `draw` (the true shelf with that draw's masses; `config`: our physics
    settings, default ours): did the plan fail? None when the shelf does not come to rest there."""
    from shelfpick.planning.predict import Predictor

    ms = masses_of(truth.boxes, unit["seed"], draw, unit["mass"])
    scene = replace(truth, boxes=tuple(replace(b, mass=m) for b, m in zip(truth.boxes, ms)))
    try:
        with Predictor(scene, samples=1, seed=unit["seed"] + draw, model=pinned_model(), config=config) as p:
            return _fails_of(p, unit["sequence"], 1)[0]
    except SceneError:     # this draw's shelf does not come to rest in our world: no verdict
        return None


def pinned_fails(truth, unit: dict) -> list[bool | None]:
    """Our worlds, one per reference draw: the true shelf with that draw's masses, all else pinned."""
    return [pinned_fail(truth, unit, d) for d in range(unit["draws"])]


def condition_fails(truth, unit: dict, overrides: dict, hide: bool) -> list[bool]:
    from shelfpick.planning.predict import Predictor
    from shelfpick.planning.uncertainty import Uncertainty

    scene = truth.hide_depths() if hide else truth
    scene = replace(scene, boxes=tuple(replace(b, mass=None) for b in scene.boxes))
    try:
        with Predictor(scene, samples=unit["draws"], seed=unit["seed"], model=replace(Uncertainty(), **overrides)) as p:
            return _fails_of(p, unit["sequence"], unit["draws"])
    except SceneError:         # no world can be built: the gate would refuse the shelf
        return []


GATE_ONLY = ("pinned physics, our masses", "+ depths hidden", "+ lift or drag")


def run_unit(unit: dict) -> dict:
    """One plan: its reference and our conditions' per-world failures. With `gate_only`, the
    reference's failing draws in detail, the gate's own worlds (seed 0: 0-9 the search's, 10-19 the
    gate's) and the few conditions that tell physics from priors (GATE_ONLY)."""
    from shelfpick.perception.scene import Scene

    warnings.simplefilter("ignore")
    truth_json = json.loads(unit["truth"])
    truth = Scene.from_json(truth_json)
    row = {k: unit[k] for k in ("shelf", "target", "sequence", "draws", "declared_safe")}
    detail: list = []
    row["reference"] = {e: reference_fails(truth_json, unit, e, detail if e == unit["engines"][0] else None)
                        for e in unit["engines"]}
    row["reference_detail"] = detail
    row["pinned"] = pinned_fails(truth, unit)
    conds = conditions(tuple(unit["mass"]))
    if unit.get("gate_only"):
        conds = {k: conds[k] for k in GATE_ONLY}
    row["conditions"] = {name: condition_fails(truth, unit, ov, hide) for name, (ov, hide) in conds.items()}
    if unit.get("gate_only"):   # 20 worlds at least: the search's ten and the gate's first ten
        row["conditions"][SEARCH] = condition_fails(truth, {**unit, "seed": 0, "draws": max(20, unit["draws"])}, {}, True)
    return row


def truth_of(shelf: str):
    """The true shelf of a row's `shelf` name ("kind-seed"), generated and settled as the rows' were."""
    from shelfpick.planning.shelves import generate

    kind, seed = shelf.rsplit("-", 1)
    return generate(kind, int(seed), settle=True)


def add_unit(unit: dict) -> dict:
    """The conditions of `unit["add"]` for a row made before: the row with them merged in."""
    warnings.simplefilter("ignore")
    truth = truth_of(unit["shelf"])
    row = dict(unit["row"])
    if unit["add"] == "mujoco":
        unit = {**unit, "target": row["target"], "mass": unit["mass"]}
        row["reference"] = {**row["reference"], "mujoco": reference_fails(truth.to_json(), unit, "mujoco")}
        return row
    if unit["add"] == "search":    # the worlds the plan was searched in (make_plan's seed 0), 20 of them
        row["conditions"] = {**row["conditions"], SEARCH: condition_fails(truth, {**unit, "seed": 0}, {}, True)}
        return row
    row["conditions"] = {**row["conditions"], **{name: condition_fails(truth, unit, ov, hide)
                                                 for name, (ov, hide) in unit["add"].items()}}
    return row


def plan_units(a: argparse.Namespace) -> list[dict]:
    """The shelves and the planner's plans (made here, in this process, as `shelfpick plan` makes them)."""
    import numpy as np

    from shelfpick.planning.planner import make_plan
    from shelfpick.planning.shelves import generate

    units = []
    lo, hi = a.seeds
    for kind in a.kinds:
        for s in range(lo, hi + 1):
            truth = generate(kind, s, settle=True)
            hidden = truth.hide_depths()
            rng = np.random.default_rng([s, 7])
            for i in rng.choice(len(truth.ids), min(a.targets, len(truth.ids)), replace=False):
                target = truth.ids[int(i)]
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        plan = make_plan(hidden, "extract", target, "physics", 10, 0)
                except SceneError:
                    continue
                if not plan.sequence:
                    continue
                units.append({"shelf": f"{kind}-{s}", "target": target, "sequence": list(plan.sequence),
                              "truth": json.dumps(truth.to_json()), "draws": a.draws, "mass": list(a.mass),
                              "seed": s, "engines": a.engines, "judge_dir": a.judge,
                              "declared_safe": bool(plan.safe), "gate_only": a.gate_only})
    return units


def summary(rows: Sequence[dict], quiet: float = 0.05) -> list[dict]:
    """Per condition: mean failing share over quiet plans (reference fails in <= `quiet` of draws)
    and over all plans; and the pinned worlds' per-draw agreement with the reference."""
    def share(f: Sequence[bool | None]) -> float | None:
        got = [x for x in f if x is not None]
        return sum(got) / len(got) if got else None

    ref = [reference_of(r) for r in rows]
    quiet_rows = [r for r, f in zip(rows, ref) if share(f) <= quiet]
    out = [{"condition": f"reference ({e})", "quiet": _mean(share(r["reference"][e]) for r in quiet_rows),
            "all": _mean(share(r["reference"][e]) for r in rows)} for e in rows[0]["reference"]] if rows else []
    agree = [a == b for r, f in zip(rows, ref) for a, b in zip(r["pinned"], f) if a is not None]
    out.append({"condition": "pinned (same masses as the reference)", "quiet": _mean(share(r["pinned"]) for r in quiet_rows),
                "all": _mean(share(r["pinned"]) for r in rows), "agreement": _mean(agree)})
    for name in (rows[0]["conditions"] if rows else ()):
        out.append({"condition": name, "quiet": _mean(share(r["conditions"][name]) for r in quiet_rows),
                    "all": _mean(share(r["conditions"][name]) for r in rows),
                    "quiet_plans_failing_5pct_or_less": sum((share(r["conditions"][name]) or 0) <= quiet
                                                           for r in quiet_rows if r["conditions"][name]),
                    "no_world": sum(not r["conditions"][name] for r in rows)})
    return out


def gate_windows(rows: Sequence[dict], max_risk: float = 0.05) -> list[dict]:
    """The shipped gate's calibrated map applied to windows of worlds (rows with `--add search`):
    the search's own 0-9, the ten after them, 20 of another seed. Per window and reference engine:
    plans declared safe, their mean reference failing share, the AUC of the calibrated chance
    against "the reference fails in more than 5% of draws", and quiet plans declared safe."""
    from shelfpick.planning.calibration import calibration_for
    from shelfpick.planning.uncertainty import Uncertainty

    cal = calibration_for(Uncertainty().pull_modes)
    windows = {"the search's own, 0-9": lambda r: r["conditions"][SEARCH][:10],
               "the next ten, 10-19": lambda r: r["conditions"][SEARCH][10:20],
               "20 of another seed": lambda r: r["conditions"]["default cell (all of them)"][:20]}
    if "default cell (all of them)" not in rows[0]["conditions"]:    # --gate-only rows
        del windows["20 of another seed"]
    out = []
    for name, pick in windows.items():
        for eng in rows[0]["reference"]:
            got = []
            for r in rows:
                w = [x for x in pick(r) if x is not None]
                if w:
                    k, n = sum(w), len(w)
                    ref = sum(r["reference"][eng]) / len(r["reference"][eng])
                    got.append((cal.probability(k, n), cal.interval(k, n)[1] < max_risk, ref))
            safe = [ref for _, s, ref in got if s]
            pos = [p for p, _, ref in got if ref > max_risk]
            neg = [p for p, _, ref in got if ref <= max_risk]
            auc = sum((a > b) + 0.5 * (a == b) for a in pos for b in neg) / (len(pos) * len(neg)) if pos and neg else float("nan")
            out.append({"window": name, "engine": eng, "plans": len(got), "safe": len(safe),
                        "safe_mean_ref": _mean(safe), "auc": round(auc, 3),
                        "quiet_safe": sum(1 for _, s, ref in got if s and ref <= max_risk), "quiet": len(neg)})
    return out


def by_gate_failures(rows: Sequence[dict]) -> list[dict]:
    """Rows with the gate's own worlds (`--gate-only`, `--add search`), grouped by how many of the
    gate's first ten (10-19) failed: plans, declared safe, the shipped map's chance for that count,
    and the reference's mean failing share (first engine). Does the count still rank the plans the
    map gives one chance?"""
    from shelfpick.planning.calibration import calibration_for
    from shelfpick.planning.uncertainty import Uncertainty

    cal = calibration_for(Uncertainty().pull_modes)
    groups: dict[int, list[dict]] = {}
    for r in rows:
        w = [x for x in r["conditions"][SEARCH][10:20] if x is not None]
        if w:
            groups.setdefault(sum(w), []).append(r)
    out = []
    for k in sorted(groups):
        g = groups[k]
        ref = [sum(reference_of(r)) / len(reference_of(r)) for r in g]
        out.append({"failed_of_10": k, "plans": len(g), "declared_safe": sum(r["declared_safe"] for r in g),
                    "map_chance": round(cal.probability(k, 10), 4), "reference_mean": _mean(ref),
                    "reference_over_5pct": sum(x > 0.05 for x in ref)})
    return out


def in_expectation(rows: Sequence[dict]) -> dict:
    """Over the reference's mass draws (first engine), each plan failing with its share p: the
    expected AUC of each risk (a condition's failing share of worlds, the pinned worlds', the gate's
    first ten, the shipped gate's verdict); the shipped gate's "safe" plans, their mean p and the
    share of holding plans they make up; of the reference's failing draws on "safe" plans with p
    over 5 %, how many our pinned world also fails; and per draw, where the two disagree."""
    from benchmarks.gate_mass_ceiling import expected_auc

    def share(f: Sequence[bool | None]) -> float:
        got = [x for x in f if x is not None]
        return sum(got) / len(got) if got else 1.0      # no world built: the gate refuses, the worst risk

    ref = [reference_of(r) for r in rows]
    ps = [sum(f) / len(f) for f in ref]
    risks = {"pinned (same masses)": [share(r["pinned"]) for r in rows]}
    risks.update({name: [share(r["conditions"][name]) for r in rows] for name in (rows[0]["conditions"] if rows else ())})
    if rows and SEARCH in rows[0]["conditions"]:
        risks["the gate's first ten worlds (10-19)"] = [share(r["conditions"][SEARCH][10:20]) for r in rows]
    risks["the shipped gate's verdict"] = [0.0 if r["declared_safe"] else 1.0 for r in rows]
    safe = [p for r, p in zip(rows, ps) if r["declared_safe"]]
    hold = sum(1 - p for p in ps)
    missed = [(r, f) for r, f, p in zip(rows, ref, ps) if r["declared_safe"] and p > 0.05]
    per_draw = confusion(rows, lambda r: r["pinned"])
    return {"auc": {k: expected_auc(v, ps) for k, v in risks.items()},
            "safe": len(safe), "safe_mean_share": _mean(safe),
            "held_safe_share": round(sum(1 - p for p in safe) / hold, 3) if hold else float("nan"),
            "risky_safe_plans": len(missed), "their_failing_draws": sum(sum(f) for _, f in missed),
            "also_failing_pinned": sum(1 for r, f in missed for a, b in zip(r["pinned"], f) if a and b),
            "only_ours_fail": per_draw["reference holds, ours fails"],
            "only_reference_fails": per_draw["reference fails, ours holds"]}


def reference_of(row: dict) -> list[bool]:
    """A row's per-draw failures on its first reference engine (the one the detail is kept for)."""
    return row["reference"][next(iter(row["reference"]))]


def confusion(rows: Sequence[dict], fails_of) -> dict[str, int]:
    """Per draw against the reference (`reference_of`): both fail, misses, false alarms, both hold, and
    draws where ours did not come to rest; `fails_of(row)` gives our per-draw verdicts."""
    out = {"both fail": 0, "reference fails, ours holds": 0, "reference holds, ours fails": 0,
           "both hold": 0, "no rest": 0}
    for r in rows:
        for a, b in zip(reference_of(r), fails_of(r)):
            key = ("no rest" if b is None else "both fail" if a and b else "reference fails, ours holds" if a
                   else "reference holds, ours fails" if b else "both hold")
            out[key] += 1
    return out


def _mean(xs) -> float:
    xs = [x for x in xs if x is not None]
    return round(sum(xs) / len(xs), 3) if xs else float("nan")


def report(rows: Sequence[dict], png: str | None) -> None:
    ref = [reference_of(r) for r in rows]
    nq = sum(sum(f) <= 0.05 * len(f) for f in ref)
    print(f"{len(rows)} plans on {len({r['shelf'] for r in rows})} shelves; {nq} quiet on the reference "
          f"(fail in <= 5% of its mass draws)")
    ds = [(r["declared_safe"], sum(f) / len(f)) for r, f in zip(rows, ref)]
    safe = [x for d, x in ds if d]
    print(f"the default gate declared {len(safe)} safe: {sum(x <= 0.05 for x in safe)} of them quiet, "
          f"mean reference failing share {_mean(safe)}; of the {nq} quiet plans it declared "
          f"{sum(d for d, x in ds if x <= 0.05)} safe")
    print("| condition | mean failing share, quiet plans | all plans | quiet plans <= 5% here |")
    print("|---|---:|---:|---:|")
    for s in summary(rows):
        extra = s.get("quiet_plans_failing_5pct_or_less", s.get("agreement", ""))
        if s.get("no_world"):
            extra = f"{extra} ({s['no_world']} plans: no world built)"
        if "agreement" in s:
            extra = f"agrees per draw {s['agreement']:.2f}"
        print(f"| {s['condition']} | {s['quiet']} | {s['all']} | {extra} |")
    if rows and SEARCH in rows[0]["conditions"]:
        print("\nThe shipped gate's map on windows of worlds (declared safe; their mean reference failing share; "
              "AUC against reference > 5%; quiet plans declared safe):")
        for g in gate_windows(rows):
            print(f"| {g['window']} | {g['engine']} | {g['safe']}/{g['plans']} | {g['safe_mean_ref']} | {g['auc']} | "
                  f"{g['quiet_safe']}/{g['quiet']} |")
        print("\nBy the gate's failing worlds of its first ten (10-19): plans, declared safe, the map's chance for "
              "that count, the reference's mean failing share, plans it fails in > 5% of draws:")
        for g in by_gate_failures(rows):
            print(f"| {g['failed_of_10']} | {g['plans']} | {g['declared_safe']} | {g['map_chance']} | "
                  f"{g['reference_mean']} | {g['reference_over_5pct']} |")
    e = in_expectation(rows)
    print(f"\nIn expectation over the reference's draws: the gate calls {e['safe']} safe, failing in "
          f"{e['safe_mean_share']:.1%} of draws, {e['held_safe_share']:.0%} of the holding plans; of the "
          f"{e['their_failing_draws']} failing draws of its {e['risky_safe_plans']} 'safe' plans over 5 %, our pinned "
          f"worlds fail {e['also_failing_pinned']}; per draw, only ours fail {e['only_ours_fail']}, only the "
          f"reference {e['only_reference_fails']}. Expected AUC of each risk:")
    for name, auc in e["auc"].items():
        print(f"| {name} | {auc} |")
    if png:
        plot(rows, png)


def plot(rows: Sequence[dict], path: str) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    s = summary(rows)
    fig, ax = plt.subplots(figsize=(8, 0.4 * len(s) + 1.2))
    ys = range(len(s))
    ax.barh([y + 0.2 for y in ys], [r["quiet"] for r in s], 0.4, label="quiet plans (reference <= 5%)")
    ax.barh([y - 0.2 for y in ys], [r["all"] for r in s], 0.4, label="all plans")
    ax.set_yticks(list(ys), [r["condition"] for r in s], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlabel("mean share of worlds (draws) in which the plan fails")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kinds", default="structured,unstructured")
    ap.add_argument("--seeds", default="41000-41007", help="LOW-HIGH, shelf seeds of this script's own")
    ap.add_argument("--targets", type=int, default=2)
    ap.add_argument("--draws", type=int, default=20)
    ap.add_argument("--mass", type=float, nargs=2, default=(0.5, 3.0), metavar=("LOW", "HIGH"))
    ap.add_argument("--engines", default="pybullet")
    ap.add_argument("--judge", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", required=True)
    ap.add_argument("--from-rows", action="store_true")
    ap.add_argument("--gate-only", action="store_true",
                    help="the reference in detail, the gate's own worlds and the conditions of GATE_ONLY only "
                         "(where the gate calls a plan quiet that the reference fails: physics or priors?)")
    ap.add_argument("--png")
    ap.add_argument("--add", choices=("contact", "mujoco", "search", "modes"),
                    help="merge into the rows in --out: the contact-friction conditions, MuJoCo's reference, "
                         "the default cell in the worlds the plan was searched in (seed 0: the first 10 chose it), "
                         "or the default cell with its pull known (drag only, lift only)")
    a = ap.parse_args(argv)
    try:
        lo, hi = (int(x) for x in a.seeds.split("-"))
    except ValueError:
        raise UsageError(f"--seeds: expected LOW-HIGH, got {a.seeds!r}") from None
    a.seeds = (lo, hi)
    a.kinds = [k for k in a.kinds.split(",") if k]
    a.engines = [e for e in a.engines.split(",") if e]
    if a.draws < 1:
        raise UsageError(f"--draws: expected a positive number, got {a.draws}")
    return a


def main(argv: Sequence[str] | None = None) -> int:
    try:
        a = parse_args(argv)
    except UsageError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if a.from_rows:
        rows = [json.loads(x) for x in Path(a.out).read_text().splitlines() if x.strip()]
        report(rows, a.png)
        return 0
    from tqdm import tqdm

    if a.add:
        old = [json.loads(x) for x in Path(a.out).read_text().splitlines() if x.strip()]
        extra = contact_conditions(tuple(a.mass)) if a.add == "contact" else \
            mode_conditions() if a.add == "modes" else a.add
        units = [{"shelf": r["shelf"], "row": r, "add": extra, "sequence": r["sequence"], "draws": r["draws"],
                  "seed": int(r["shelf"].rsplit("-", 1)[1]), "judge_dir": a.judge, "mass": list(a.mass)} for r in old]
        rows = list(tqdm(iter_rows(units, a.jobs, add_unit), total=len(units), desc="plans", file=sys.stderr))
        Path(a.out).write_text("".join(json.dumps(r) + "\n" for r in rows))
        report(rows, a.png)
        return 0
    units = plan_units(a)
    rows = [json.loads(x) for x in Path(a.out).read_text().splitlines() if x.strip()] if Path(a.out).exists() else []
    done = {(r["shelf"], r["target"]) for r in rows}
    units = [u for u in units if (u["shelf"], u["target"]) not in done]
    with open(a.out, "a") as f:
        for row in tqdm(iter_rows(units, a.jobs, run_unit), total=len(units), desc="plans", file=sys.stderr):
            rows.append(row)
            f.write(json.dumps(row) + "\n")
            f.flush()
    report(rows, a.png)
    return 0


if __name__ == "__main__":
    sys.exit(main())
