"""Where our pinned worlds fail a plan the judge's engine holds: which physics setting of ours is it?

Reads rows of `world_ablation.py` (`--gate-only` or full) made on OUR OWN shelves. For every plan
the reference (the judge's engine, imported by world_ablation, never copied) holds in all its mass
draws, each draw in which our pinned world (the same masses, the reference's pull and friction)
fails is run again under variants of our physics settings (`VARIANTS`: the time step, the seeded
vibration, the end-of-step threshold, the force limit, the gripper's body, the speed ramp, ...). A
variant that turns most of these failures into holds is a difference of our physics from the
reference's; none doing so says the difference is deeper (the contact model, the shelf, settling).

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/pinned_knobs.py ROWS.jsonl [ROWS.jsonl ...] [--limit 20] [--mujoco]

`--mujoco` also runs each draw on the judge's other engine (MuJoCo, the same masses and pull): a
draw it fails is one the judge's own two engines disagree on.

A variant that clears false alarms may also miss real failures. `--both-sides VARIANT` runs every
draw of every plan under one variant and scores it against the reference beside the rows' own
pinned worlds: both fail, misses, false alarms, both hold (`--out` keeps the per-plan rows):

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/pinned_knobs.py ROWS.jsonl ... --both-sides "VARIANT" --jobs 2 [--out F]
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks import world_ablation as wa  # noqa: E402

_JUDGE_LIKE = {"time_step": 1 / 240, "disturbance": 0.0, "disturbance_force": 0.0, "collapse_displacement": 0.03,
               "pull_force_weights": 1000.0, "pull_margin": 0.05}
VARIANTS: dict[str, dict] = {
    "as is": {},
    "time step 1/240 s": {"time_step": 1 / 240},
    "no vibration": {"disturbance": 0.0, "disturbance_force": 0.0},
    "end threshold 3 cm": {"collapse_displacement": 0.03},
    "force limit 150 N whatever the weight": {"pull_force_weights": 1000.0},
    "no gripper body": {"gripper_size": (0.001, 0.001, 0.001)},
    "no speed ramp": {"pull_ramp": 0.0},
    "the box may turn, its centre held": {"pull_turn": True},
    "a cup soft in height (hold_spring)": {"hold_spring": True},
    "the same, carrying a dragged box's weight": {"hold_spring": True, "hold_carry": 1.0},
    "the same, carrying 0.6 of it (the rigid hold's share)": {"hold_spring": True, "hold_carry": 0.6},
    "all of the above but the body and ramp": _JUDGE_LIKE,
}


def false_alarms(rows: Sequence[dict], limit: int) -> list[tuple[dict, int]]:
    """(row, draw) for each draw our pinned world fails of a plan the reference holds in every draw."""
    out = []
    for r in rows:
        if any(wa.reference_of(r)):
            continue
        out += [(r, d) for d, f in enumerate(r["pinned"]) if f]
    return out[:limit]


def _unit(row: dict, mass: tuple[float, float]) -> dict:
    return {"target": row["target"], "sequence": row["sequence"], "seed": int(row["shelf"].rsplit("-", 1)[1]),
            "mass": mass}


def run_draw(truth, row: dict, draw: int, mass: tuple[float, float]) -> dict[str, bool | None]:
    """Per variant: does our pinned world (world_ablation's) fail this draw of `row` on `truth`?"""
    from shelfpick.planning.physics import PhysicsConfig

    unit = _unit(row, mass)
    return {name: wa.pinned_fail(truth, unit, draw, replace(PhysicsConfig(), **changes))
            for name, changes in VARIANTS.items()}


def mujoco_fails(truth_json: dict, row: dict, draw: int, mass: tuple[float, float], judge_dir: str) -> bool:
    """The judge's MuJoCo engine on the true shelf with this draw's masses: does the plan fail?"""
    if judge_dir not in sys.path:
        sys.path.insert(0, judge_dir)
    return not wa.reference_verdict(truth_json, _unit(row, mass), "mujoco", draw)["ok"]


def _said(failed: bool | None) -> str:
    return "no rest" if failed is None else "fails" if failed else "holds"


def both_sides_unit(unit: dict) -> list[dict]:
    """Every draw of the plans of one shelf (`unit["rows"]`) in our pinned world under the variant
    `unit["variant"]`: did it fail? The shelf is generated once for all its plans."""
    from shelfpick.planning.physics import PhysicsConfig

    warnings.simplefilter("ignore")
    truth = wa.truth_of(unit["shelf"])
    config = replace(PhysicsConfig(), **VARIANTS[unit["variant"]])
    return [{"shelf": row["shelf"], "target": row["target"], "sequence": row["sequence"], "variant": unit["variant"],
             "fails": [wa.pinned_fail(truth, _unit(row, unit["mass"]), d, config) for d in range(row["draws"])]}
            for row in unit["rows"]]


def both_sides(rows: Sequence[dict], variant: str, jobs: int, mass: tuple[float, float], out: Path | None) -> None:
    """Both sides of a variant: every draw of every plan, scored against the reference beside the rows'
    own pinned worlds (our settings as they were when the rows were made)."""
    from contextlib import nullcontext

    from tqdm import tqdm

    from benchmarks.judge_rows import iter_rows

    shelves: dict[str, list[dict]] = {}
    for r in rows:
        shelves.setdefault(r["shelf"], []).append(r)
    units = [{"shelf": s, "rows": rs, "variant": variant, "mass": list(mass)} for s, rs in shelves.items()]
    got: dict[tuple, list] = {}
    with out.open("w") if out else nullcontext() as f:
        for res in tqdm(iter_rows(units, jobs, both_sides_unit), total=len(units), desc="shelves", file=sys.stderr):
            for plan in res:
                got[(plan["shelf"], plan["target"], tuple(plan["sequence"]))] = plan["fails"]
                if f:
                    f.write(json.dumps(plan) + "\n")
    print(f"per draw, {len(rows)} plans, against the reference:")
    print(f"| | as the rows were made | {variant} |\n|---|---:|---:|")
    before = wa.confusion(rows, lambda r: r["pinned"])
    after = wa.confusion(rows, lambda r: got[(r["shelf"], r["target"], tuple(r["sequence"]))])
    for key in before:
        print(f"| {key} | {before[key]} | {after[key]} |")


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("rows", nargs="+")
    ap.add_argument("--limit", type=int, default=40, help="at most this many failing draws")
    ap.add_argument("--mass", type=float, nargs=2, default=(0.5, 3.0), metavar=("LOW", "HIGH"),
                    help="the mass range the rows were made with (world_ablation's --mass)")
    ap.add_argument("--mujoco", action="store_true", help="also the judge's MuJoCo engine on each draw")
    ap.add_argument("--judge", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--both-sides", metavar="VARIANT", choices=list(VARIANTS),
                    help="run every draw of every plan under this variant and score both sides")
    ap.add_argument("--jobs", type=int, default=1, help="processes for --both-sides")
    ap.add_argument("--out", type=Path, help="--both-sides: per-plan rows (JSON lines)")
    a = ap.parse_args(argv)
    rows = []
    for path in a.rows:
        try:
            rows += [json.loads(x) for x in Path(path).read_text().splitlines() if x.strip()]
        except (OSError, ValueError) as exc:
            print(f"error: {path}: {exc}", file=sys.stderr)
            return 2
    warnings.simplefilter("ignore")
    if a.both_sides:
        both_sides(rows, a.both_sides, a.jobs, tuple(a.mass), a.out)
        return 0
    todo = false_alarms(rows, a.limit)
    tally = {name: 0 for name in VARIANTS}
    if a.mujoco:
        tally["the judge's MuJoCo engine"] = 0
    truths: dict = {}      # shelf -> its truth, generated (and settled) once
    for row, draw in todo:
        if row["shelf"] not in truths:
            truths[row["shelf"]] = wa.truth_of(row["shelf"])
        truth = truths[row["shelf"]]
        got = run_draw(truth, row, draw, tuple(a.mass))
        if a.mujoco:
            got["the judge's MuJoCo engine"] = mujoco_fails(truth.to_json(), row, draw, tuple(a.mass), a.judge)
        for name, failed in got.items():
            tally[name] += bool(failed)
        print(f"{row['shelf']} {row['target']} draw {draw}: " +
              "; ".join(f"{n}: {_said(f)}" for n, f in got.items()), flush=True)
    print(f"\n{len(todo)} draws our pinned worlds fail of plans the reference holds in every draw; still failing under:")
    for name, n in tally.items():
        print(f"| {name} | {n} of {len(todo)} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
