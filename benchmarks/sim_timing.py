"""Measure the simulation's cost and its accuracy against a fine-step reference.

    python -m benchmarks.sim_timing timing             # single trial, Predictor.trial (10 samples)
    python -m benchmarks.sim_timing accuracy [--quick] # verdicts of coarse settings vs 1/480 s
    python -m benchmarks.sim_timing locality [--quick] # local trials vs the full simulation

The figures are written up in docs/physics.md. The scenes are built here so
the measurement does not depend on the synthetic-shelf generator.
"""
from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
import warnings
from pathlib import Path

from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.physics import PhysicsConfig

A = (0.31, 0.23, 0.25)   # the method's box types as (width, depth, height)
B = (0.2, 0.2, 0.2)
C = (0.5, 0.17, 0.17)


def twelve_box_scene() -> Scene:
    """12 boxes: four columns, a long box bridging two of them, fronts staggered by up to 3 cm."""
    boxes: list[Box] = []

    def add(size, x, z, dy=0.0):
        boxes.append(Box(f"b{len(boxes)}", size, (x, dy + size[1] / 2, z)))

    add(A, -0.34, 0.125, 0.0); add(A, -0.34, 0.375, 0.02); add(B, -0.34, 0.6, -0.02)
    add(B, -0.08, 0.1, 0.01); add(B, -0.08, 0.3, 0.0)
    add(B, 0.13, 0.1, -0.01); add(B, 0.13, 0.3, 0.03)
    add(C, 0.07, 0.4 + 0.085, 0.0)
    add(B, 0.36, 0.1, 0.0); add(B, 0.36, 0.3, 0.02)
    add(B, -0.34, 0.8, 0.0)
    add(B, 0.05, 0.57 + 0.1, 0.01)
    return Scene(Shelf(), tuple(boxes))


def column_scene(n: int = 6) -> Scene:
    return Scene(Shelf(), tuple(Box(f"c{i}", B, (0.0, 0.12, 0.1 + 0.2 * i)) for i in range(n))
                 + (Box("f", B, (0.35, 0.12, 0.1)),))


def timing(config: PhysicsConfig, repeat: int = 3) -> dict:
    from shelfpick.planning.predict import Predictor
    from shelfpick.planning.sim import ShelfSim

    scene = twelve_box_scene()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ShelfSim(scene, config)
    snap = sim.snapshot()
    single, single_cpu, steps = [], [], []
    for _ in range(repeat):
        for b in scene.ids:
            sim.restore(snap)
            t, c = time.perf_counter(), time.process_time()
            r = sim.remove(b, stop_on_collapse=True)
            single.append(time.perf_counter() - t)
            single_cpu.append(time.process_time() - c)
            steps.append(r.sim_time / config.time_step)
    sim.close()
    t, c = time.perf_counter(), time.process_time()
    pred = Predictor(scene.hide_depths(), samples=10, seed=0, config=config)
    build, build_cpu = time.perf_counter() - t, time.process_time() - c
    trials, trials_cpu = [], []
    for b in scene.ids:
        t, c = time.perf_counter(), time.process_time()
        pred.trial(frozenset(), b)
        trials.append(time.perf_counter() - t)
        trials_cpu.append(time.process_time() - c)
    pred.close()
    return {"single_trial_ms_p50": 1000 * statistics.median(single),
            "single_trial_ms_mean": 1000 * statistics.mean(single),
            "steps_per_trial_mean": statistics.mean(steps),
            "predictor_build_s": build,
            "predictor_trial_ms_p50": 1000 * statistics.median(trials),
            "predictor_trial_ms_mean": 1000 * statistics.mean(trials),
            "cpu": {"single_trial_ms_p50": 1000 * statistics.median(single_cpu),
                    "single_trial_ms_mean": 1000 * statistics.mean(single_cpu),
                    "predictor_build_s": build_cpu,
                    "predictor_trial_ms_p50": 1000 * statistics.median(trials_cpu),
                    "predictor_trial_ms_mean": 1000 * statistics.mean(trials_cpu)}}


def accuracy(configs: dict[str, PhysicsConfig], reference: PhysicsConfig, samples: int = 4) -> dict:
    """Collapse verdict and first collapsing box of every single-box removal, vs the reference."""
    from shelfpick.planning.uncertainty import sample_depths
    from shelfpick.planning.sim import ShelfSim

    base = twelve_box_scene().hide_depths()
    scenes = [sample_depths(base, 0, i) for i in range(samples)] + [column_scene()]
    out: dict[str, dict] = {}
    for name, cfg in [("reference", reference)] + list(configs.items()):
        verdicts, spent, n, steps = [], 0.0, 0, 0.0
        for sc in scenes:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sim = ShelfSim(sc, cfg)
            snap = sim.snapshot()
            for b in sc.ids:
                sim.restore(snap)
                t = time.process_time()   # CPU: on a shared machine wall time is mostly the others
                r = sim.remove(b, stop_on_collapse=name != "reference")
                spent += time.process_time() - t
                steps += r.sim_time / cfg.time_step
                n += 1
                verdicts.append((bool(r.collapsed), r.collapsed[0] if r.collapsed else None))
            sim.close()
        out[name] = {"verdicts": verdicts, "trial_ms": 1000 * spent / n, "steps": steps / n}
        print(f"{name}: {out[name]['trial_ms']:.1f} ms per trial", file=sys.stderr, flush=True)
    ref = out["reference"]["verdicts"]
    for name, o in out.items():
        v = o["verdicts"]
        o["collapse_agree"] = sum(a[0] == b[0] for a, b in zip(v, ref)) / len(ref)
        o["first_agree"] = sum(a == b for a, b in zip(v, ref)) / len(ref)
        o["n"] = len(ref)
    return out


def locality(scenes: dict[str, Scene], config: PhysicsConfig, samples: int = 2,
             seed: int = 0, pairs: int = 1) -> dict:
    """Local trials (neighbourhood only) against the full simulation, trial by trial.

    For every depth sample of every scene: every single-box pull, then, after
    taking away each of the first `pairs` boxes that nothing stands on, every
    pull again (the state after a removal is settled locally or fully too).
    Compares the collapse verdict, the first collapsing box and the collision
    verdict, and counts steps and CPU time of both ways.
    """
    from shelfpick.planning.uncertainty import sample_depths

    rows: list[dict] = []
    tot = {"full": [0.0, 0], "local": [0.0, 0]}
    for name, base in scenes.items():
        hidden = base.hide_depths()
        for i in range(samples):
            sc = sample_depths(hidden, seed, i, config)
            sim = _local_sim(sc, config, f"{name} sample {i}")
            if sim is None:
                continue
            rows += _sample_rows(sim, sc, config, pairs, tot, name, i)
            sim.close()
    return _locality_summary(rows, tot)


def _local_sim(sc: Scene, config: PhysicsConfig, label: str):
    """A ShelfSim that can run local trials, or None for an unstable draw (the Predictor would redraw)."""
    from shelfpick.planning.sim import ShelfSim

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            return ShelfSim(sc, config, local=True)
        except Exception as exc:  # an unstable draw: skip it, as the Predictor would redraw
            print(f"{label}: {exc}", file=sys.stderr)
            return None


def _sample_rows(sim, sc: Scene, config: PhysicsConfig, pairs: int, tot: dict, name: str, i: int) -> list[dict]:
    """One depth sample: every pull from the full shelf, then from the shelf less each of `pairs` top boxes."""
    rows = []
    base_snap = sim.snapshot()
    tops = [b for b in sc.ids if not _above(sim, b)]   # nothing stands on them
    sets = [frozenset()] + [frozenset({b}) for b in tops[:pairs]]
    for removed in sets:
        snaps = {}
        for mode in ("full", "local"):
            sim.restore(base_snap)
            sim.delete_many(sorted(removed), local=mode == "local")
            snaps[mode] = sim.snapshot()
        for b in sc.ids:
            if b in removed:
                continue
            out = _pull_three_ways(sim, snaps, b, config, tot)
            sim.restore(snaps["local"])
            rows.append({"scene": name, "sample": i, "removed": sorted(removed), "box": b,
                         "full": out["full"], "local": out["local"], "seed": out["seed"],
                         "kept": len(sim.neighbourhood([b], corridor=True)),
                         "of": len(sim.present())})
    for s_ in snaps.values():
        sim.forget(s_)
    return rows


def _pull_three_ways(sim, snaps: dict, b: str, config: PhysicsConfig, tot: dict) -> dict:
    """Pull `b` fully, locally, and fully with another vibration seed (the noise floor); CPU and steps
    of the first two are added to `tot`. Each: (collapsed, first collapsing box, collided)."""
    out = {}
    for mode in ("full", "local", "seed"):
        sim.restore(snaps["full" if mode == "seed" else mode])
        t = time.process_time()
        r = sim.remove(b, seed=8 if mode == "seed" else 7, stop_on_collapse=True,
                       local=mode == "local")
        if mode == "seed":
            out[mode] = (bool(r.collapsed), r.collapsed[0] if r.collapsed else None,
                         bool(r.collided))
            continue
        tot[mode][0] += time.process_time() - t
        tot[mode][1] += round(r.sim_time / config.time_step)
        out[mode] = (bool(r.collapsed), r.collapsed[0] if r.collapsed else None,
                     bool(r.collided))
    return out


def _locality_summary(rows: list[dict], tot: dict) -> dict:
    """Agreement of local with full trials (and of full with itself under another seed), costs, misses."""
    n = len(rows)
    agree = lambda k: sum(r["full"][k] == r["local"][k] for r in rows) / max(1, n)  # noqa: E731
    first = sum(r["full"][:2] == r["local"][:2] for r in rows) / max(1, n)
    noise = {"collapse_agree": sum(r["full"][0] == r["seed"][0] for r in rows) / max(1, n),
             "first_agree": sum(r["full"][:2] == r["seed"][:2] for r in rows) / max(1, n)}
    return {"trials": n, "collapse_agree": agree(0), "first_agree": first, "collision_agree": agree(2),
            "full_other_vibration_seed": noise,
            "kept_mean": statistics.fmean(r["kept"] / r["of"] for r in rows) if rows else 0.0,
            "cpu_s": {m: v[0] for m, v in tot.items()}, "steps": {m: v[1] for m, v in tot.items()},
            "disagree": [r for r in rows if r["full"][:2] != r["local"][:2]]}


def _above(sim, box: str) -> set[str]:
    """Boxes stacked on `box` (the part of its neighbourhood that stands on it)."""
    p = sim.client
    lo, hi = p.getAABB(sim.body(box))
    out = set()
    for b in sim.present():
        if b == box:
            continue
        olo, ohi = p.getAABB(sim.body(b))
        if (olo[0] < hi[0] - 0.005 and lo[0] + 0.005 < ohi[0] and olo[1] < hi[1] - 0.005
                and lo[1] + 0.005 < ohi[1] and olo[2] > hi[2] - 0.03):
            out.add(b)
    return out


def locality_scenes(quick: bool = False) -> dict[str, Scene]:
    """The accuracy set (12-box shelf, 6-box column) and synthetic 25-30 box shelves."""
    from shelfpick.planning.shelves import generate

    out = {"twelve": twelve_box_scene(), "column": column_scene()}
    for kind, seed, n in (("structured", 11, 28), ("unstructured", 12, 27),
                          ("structured", 13, 30), ("unstructured", 14, 29))[: 2 if quick else 4]:
        out[f"{kind}-{n}"] = generate(kind, seed, n)
    return out


def _scene_files(pattern: str) -> dict[str, Scene]:
    """The scenes a glob names (the judge's shelves are read where they are, never copied)."""
    import glob

    paths = sorted(glob.glob(pattern))
    if not paths:
        raise SystemExit(f"sim_timing: --scenes: no file matches {pattern!r}")
    return {Path(p).stem: Scene.from_json(json.loads(Path(p).read_text(encoding="utf-8"))) for p in paths}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=["timing", "accuracy", "locality"])
    ap.add_argument("--quick", action="store_true", help="accuracy on 2 depth samples only")
    ap.add_argument("--levers", action="store_true",
                    help="accuracy of the speed levers of docs/speed.md instead of the step sizes")
    ap.add_argument("--scenes", metavar="GLOB",
                    help="locality on these scene files (e.g. '../shared/judge/scenes/u*.json') "
                         "instead of the built-in set, one depth sample each")
    args = ap.parse_args(argv)
    cfg = PhysicsConfig()
    if args.what == "locality":
        if args.scenes:
            res = locality(_scene_files(args.scenes), cfg, samples=1)
        else:
            res = locality(locality_scenes(args.quick), cfg, samples=1 if args.quick else 2)
        print(json.dumps(res, indent=2))
        return 0
    if args.what == "timing":
        print(json.dumps(timing(cfg), indent=2))
        return 0
    ref = PhysicsConfig(time_step=1 / 480, solver_iterations=100, early_clear=False)
    configs = {
        "1/240 s, 50 it": cfg.replace(time_step=1 / 240, solver_iterations=50),
        "1/120 s, 50 it": cfg.replace(time_step=1 / 120, solver_iterations=50),
        "1/60 s, 50 it": cfg.replace(time_step=1 / 60, solver_iterations=50),
        "1/60 s, 30 it": cfg.replace(time_step=1 / 60, solver_iterations=30),
        "default": cfg,
    }
    if args.levers:
        configs = {
            "default": cfg,
            "rest window 0.05 s": cfg.replace(rest_window=0.05),
            "1/120 s, 30 it": cfg.replace(solver_iterations=30),
            "1/90 s, 50 it": cfg.replace(time_step=1 / 90),
            "no lift (dragged, z free)": cfg.replace(pull_lift=0.0),
        }
    res = accuracy(configs, ref, samples=2 if args.quick else 4)
    for name, o in res.items():
        print(f"| {name} | {o['collapse_agree']:.3f} | {o['first_agree']:.3f} | {o['trial_ms']:.1f} "
              f"| {o['steps']:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
