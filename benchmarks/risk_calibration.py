"""Our own perturbed-truth bench for the risk calibration (issue 32): collect, then fit.

    .venv/bin/python benchmarks/risk_calibration.py collect --out cal.jsonl [--scenes 3] [--seed 11] [--worlds 30]
    .venv/bin/python benchmarks/risk_calibration.py fit cal.jsonl --json planning/calibration.json \
        --png docs/img/risk-reliability.png --md docs/results/risk-gate-fit.md

`collect`: shelves from our own generator (`planning.shelves`, every kind, 8-14 boxes, seeds of
their own), a truth drawn per shelf (`planning.bench.true_world`: true masses, another friction,
a drag without lift, another speed and force limit), what the camera gives (`bench.observe`, 0 or
1 cm of error). Steps come from two sources: every box pulled alone from the full shelf, and every
step of the physics plan for a few targets per shelf (up to and including the truth's first
collapse). Each step is asked of `--worlds` sample worlds (`Predictor.results`: the per-world
verdicts, so a prefix of them is what fewer worlds would have said) and executed on the truth
(`execute_plan`). One JSON line per step. The judge in ../shared/judge is never read.

`fit`: the map from the fraction of collapsing worlds to a probability of collapse
(`planning.calibration.fit`), its reliability table and diagram (held-out half of the shelves
against the half fitted on, and all), written where asked.
"""
from __future__ import annotations

import argparse
import json
import random
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

KINDS = ("structured", "unstructured", "proud", "bridge", "lean", "overhang")


def _near(r, cfg) -> float:
    """How near a world came to a collapse: the largest other box's end-of-step displacement or
    turn as a share of the collapse thresholds (1 or more: past them)."""
    d = max((v / cfg.collapse_displacement for v in r.displacement.values()), default=0.0)
    a = max((v / cfg.collapse_rotation for v in r.rotation.values()), default=0.0)
    return round(max(d, a), 3)


def _world_flags(results, cfg=None) -> dict[str, list]:
    """Per world: collapsed, collided, stuck (0/1 each), and how near it came to a collapse."""
    from shelfpick.planning.physics import PhysicsConfig

    cfg = cfg or PhysicsConfig()
    return {"c": [int(bool(r.collapsed)) for r in results], "x": [int(bool(r.collided)) for r in results],
            "s": [int(r.note.startswith("stuck")) for r in results], "m": [_near(r, cfg) for r in results]}


def _truth_step(st, cfg) -> dict:
    """What the truth did at one step: our collapse verdict, and the end-state one (a box that ends
    more than the end-of-step thresholds away; a box that rocked and came back is not counted)."""
    end = any(d > cfg.collapse_displacement for d in st.displacement.values()) or \
        any(a > cfg.collapse_rotation for a in st.rotation.values())
    return {"collapse": bool(st.collapsed), "end_collapse": bool(end), "extracted": bool(st.extracted)}


def collect_scene(kind: str, seed: int, noise: float, worlds: int, targets: int, base_seed: int,
                  truth_pull: str = "drag", pull_modes: tuple[str, ...] | None = None,
                  skip: int = 10) -> list[dict]:
    """Every row of one shelf at one noise level; the evidence is `worlds` sample worlds after the
    first `skip` (the search's own ten: the gate asks the worlds after them, `planning.gate`)."""
    from shelfpick.perception.errors import SceneError
    from shelfpick.planning.bench import derive_seed, observe, true_world, TruthModel
    from shelfpick.planning.execute import execute_plan
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.planner import make_plan
    from shelfpick.planning.predict import Predictor
    from shelfpick.planning.shelves import generate
    from shelfpick.planning.uncertainty import Uncertainty

    name = f"{kind}-{seed}"
    scene = generate(kind, seed, None)
    try:
        truth, physics, _ = true_world(scene, _truth_model(truth_pull, noise, derive_seed(base_seed, name, "lift")),
                                       derive_seed(base_seed, name, "truth"))
    except SceneError:
        return []
    seen = observe(truth, noise, derive_seed(base_seed, name, noise, "observe"))
    plan_seed = derive_seed(base_seed, name, "plan")
    # the worlds' pull modes: the cell's prior (None: the default, lift or drag)
    model = Uncertainty() if pull_modes is None else Uncertainty(pull_modes=tuple(pull_modes))
    rows: list[dict] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            counter = Predictor(seen, samples=worlds + skip, seed=plan_seed, model=model)
        except SceneError:
            return []
        planner = Predictor(seen, samples=10, seed=plan_seed, model=model)
    stands = bool(counter.scene_check.get("stands_as_seen", True))
    stands10 = bool(planner.scene_check.get("stands_as_seen", True))
    common = {"scene": name, "kind": kind, "noise": noise, "n_boxes": len(scene.boxes), "truth_pull": truth_pull,
              "truth_lift": physics.pull_lift, "pull_modes": list(model.pull_modes),
              "stands": stands, "stands10": stands10, "worlds": counter.worlds, "skip": skip}
    cfg = PhysicsConfig()
    try:
        # every box pulled alone from the full shelf
        for i, b in enumerate(truth.ids):
            flags = _world_flags(counter.results(frozenset(), b)[skip:], cfg)
            ex = execute_plan(truth, [b], seed=derive_seed(base_seed, name, "alone", b), config=physics)
            rows.append(dict(common, source="alone", box=b, removed=[], **flags,
                             **_truth_step(ex.steps[0], cfg)))
        rng = random.Random(derive_seed(base_seed, name, "targets"))
        for target in rng.sample(list(truth.ids), min(targets, len(truth.ids))):
            plan = make_plan(seen, "extract", target, "physics", 10, plan_seed, predictor=planner)
            ex = execute_plan(truth, plan.sequence, seed=derive_seed(base_seed, name, target), config=physics)
            removed: list[str] = []
            # every step, also past the truth's first collapse: the plan's worlds need all of them
            for k, (b, st) in enumerate(zip(plan.sequence, ex.steps)):
                flags = _world_flags(counter.results(frozenset(removed), b)[skip:], cfg)
                rows.append(dict(common, source="plan", target=target, step=k, steps=len(plan.sequence),
                                 box=b, removed=list(removed), **flags, plan_ok=bool(ex.ok),
                                 plan_safe=bool(plan.safe), **_truth_step(st, cfg)))
                removed.append(b)
    finally:
        counter.close()
        planner.close()
    return rows


def _truth_model(pull: str, noise: float, seed: int):
    """The bench's truth (planning.bench.TruthModel) with the gripper's pull: `drag` (the bench's
    own: no lift, the box rides on its support) or `lift` (the gripper lifts 3-8 mm first where
    nothing rests on the box, as the planner's own pull does; the height drawn per shelf)."""
    from shelfpick.planning.bench import TruthModel

    if pull == "drag":
        return TruthModel(noise=noise)
    if pull == "hold":
        return TruthModel(noise=noise, pull_hold=True)
    return TruthModel(noise=noise, pull_lift=round(random.Random(seed).uniform(0.003, 0.008), 4))


def near_plans(rows: list[dict]) -> list[dict]:
    """Per plan (a box pulled alone, or a physics plan): per world whether some step failed, and how
    near it came to a collapse (`m`, its largest step's; 1 for a failing world), and the truth's verdict."""
    from collections import defaultdict

    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in rows:
        key = (r["scene"], r["noise"], "alone", r["box"]) if r["source"] == "alone" else \
            (r["scene"], r["noise"], "plan", r["target"])
        groups[key].append(r)
    out = []
    for key, steps in groups.items():
        n = min(len(r["c"]) for r in steps)
        fails = [int(any(r["c"][i] or r["s"][i] for r in steps)) for i in range(n)]
        near = [1.0 if fails[i] else min(1.0, max(r["m"][i] for r in steps)) for i in range(n)]
        failed = (steps[0]["collapse"] or not steps[0]["extracted"]) if key[2] == "alone" else not steps[0]["plan_ok"]
        out.append({"fails": fails, "near": near, "failed": bool(failed)})
    return out


def near_report(rows_path: str) -> str:
    """Does how near the worlds came to a collapse rank plans beyond the share of failing worlds?
    AUCs against the truth's verdict, over all plans and over the plans no world failed."""
    from benchmarks.risk_gate_split import auc

    ps = near_plans([json.loads(line) for line in Path(rows_path).read_text().splitlines() if line.strip()])
    lines = [f"{rows_path}: {len(ps)} plans, {sum(p['failed'] for p in ps)} failed on the truth"]
    for n in (10, 20, 30):
        y = [p["failed"] for p in ps]
        share = [sum(p["fails"][:n]) / n for p in ps]
        near = [sum(p["near"][:n]) / n for p in ps]
        quiet = [i for i, s in enumerate(share) if s == 0]
        lines.append(f"{n} worlds: AUC share {auc(share, y):.3f}, near {auc(near, y):.3f}; "
                     f"{len(quiet)} plans no world failed ({sum(y[i] for i in quiet)} failed on the truth): "
                     f"AUC of near among them {auc([near[i] for i in quiet], [y[i] for i in quiet]):.3f}")
    return "\n".join(lines)


def _job(args: tuple) -> list[dict]:
    return collect_scene(*args)


def collect(out: str, scenes: int, seed: int, worlds: int, targets: int, noises: tuple[float, ...],
            jobs: int, truth_pull: str = "drag", pull_modes: tuple[str, ...] | None = None,
            kinds: tuple[str, ...] = KINDS, skip: int = 10) -> None:
    """Every kind x `scenes` shelves x each noise level, appended to `out` as JSON lines."""
    todo = [(k, seed + i, nz, worlds, targets, seed, truth_pull, pull_modes, skip) for k in kinds for i in range(scenes)
            for nz in noises]
    done = set()
    p = Path(out)
    if p.exists():
        for line in p.read_text().splitlines():
            r = json.loads(line)
            done.add((r["scene"], r["noise"]))
    todo = [t for t in todo if (f"{t[0]}-{t[1]}", t[2]) not in done]
    t0 = time.perf_counter()
    with open(out, "a") as fh:
        if jobs > 1:
            from multiprocessing import get_context

            with get_context("spawn").Pool(jobs) as pool:
                for rows in pool.imap_unordered(_job, todo):
                    fh.write("".join(json.dumps(r) + "\n" for r in rows))
                    fh.flush()
                    print(f"{time.perf_counter() - t0:.0f}s {rows[0]['scene'] if rows else '-'}", flush=True)
        else:
            for t in todo:
                rows = _job(t)
                fh.write("".join(json.dumps(r) + "\n" for r in rows))
                fh.flush()
                print(f"{time.perf_counter() - t0:.0f}s {t[0]}-{t[1]} noise {t[2]}: {len(rows)} steps", flush=True)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    c = sub.add_parser("collect")
    c.add_argument("--out", required=True)
    c.add_argument("--scenes", type=int, default=3, help="shelves per kind")
    c.add_argument("--seed", type=int, default=11)
    c.add_argument("--worlds", type=int, default=30)
    c.add_argument("--targets", type=int, default=3, help="plan targets per shelf")
    c.add_argument("--noise", default="0,0.01")
    c.add_argument("--jobs", type=int, default=1)
    c.add_argument("--truth-pull", choices=("drag", "hold", "lift"), default="drag",
                   help="how the truth's gripper pulls: drag (no lift, the box rides on its support, its height "
                        "free: the bench's), hold (no lift, the arm holds its height: the worlds' drag) or lift "
                        "(3-8 mm first)")
    c.add_argument("--pull-modes", default=None,
                   help="the sample worlds' pull modes, comma-separated (default: the planner's, lift,drag)")
    c.add_argument("--kinds", default=",".join(KINDS), help="shelf kinds, comma-separated")
    c.add_argument("--skip", type=int, default=10,
                   help="sample worlds left out before the evidence (the search's own: the gate asks those after them)")
    nr = sub.add_parser("near", help="how near the worlds came to a collapse, as a ranking (rows of --skip runs)")
    nr.add_argument("rows")
    f = sub.add_parser("fit")
    f.add_argument("rows")
    f.add_argument("--json")
    f.add_argument("--png")
    f.add_argument("--md")
    f.add_argument("--collisions", action="store_true",
                   help="a world fails also where a neighbour was knocked (collided), not only collapsed or stuck")
    a = ap.parse_args(argv)
    if a.cmd == "collect":
        collect(a.out, a.scenes, a.seed, a.worlds, a.targets, tuple(float(v) for v in a.noise.split(",")), a.jobs,
                a.truth_pull, tuple(a.pull_modes.split(",")) if a.pull_modes else None, tuple(a.kinds.split(",")),
                a.skip)
        return 0
    if a.cmd == "near":
        print(near_report(a.rows))
        return 0
    from benchmarks.risk_fit import run_fit

    return run_fit(a.rows, a.json, a.png, a.md, a.collisions)


if __name__ == "__main__":
    raise SystemExit(main())
