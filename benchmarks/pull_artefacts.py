"""The pull's model artefacts of issue 32, on the demo shelf and on the calibration bench's truths.

    .venv/bin/python benchmarks/pull_artefacts.py demo [--box b4] [--worlds 40] [--physics JSON] [--run-out]
        [--pull-modes lift,drag]
    .venv/bin/python benchmarks/pull_artefacts.py truth [--physics JSON]
    .venv/bin/python benchmarks/pull_artefacts.py pinned [--shelf S] [--box B] [--below B,B] [--draw D] [--seeds 8]

`demo`: `static/demo/demo-small-6.json` with depths hidden, plan seed 0, `--worlds` sample worlds
(`SampleWorlds`, as the Predictor builds them), `--box` pulled from the full shelf in each; every
world in which something collapsed, with its pull mode, masses, friction, force limit, the largest
normal force the pulled box put on the boxes under it (against its weight), and each collapsed
box's end and peak displacement. `--run-out`: the trial is not stopped at the first collapse (the
Predictor stops it), so a box that came back shows its end. `--physics`: PhysicsConfig overrides,
e.g. '{"hold_spring": true, "peak_tipping": true, "edge_perch": 0.005}'.

`pinned`: one of world_ablation's pinned worlds (`--shelf`, `--draw`: the true shelf with that
draw's masses, the reference's pull and friction) in one full simulation, `--box` dragged off the
column `--below` once per pull seed (the vibration): what collapsed, the push on the boxes below
at the start of the pull and at its peak (in the pulled box's weights), and Coulomb's estimate of
the column's tipping and restoring moments with the whole weight on it.

    .venv/bin/python benchmarks/pull_artefacts.py pinned --shelf structured-43003 --box b10 --below b8,b5,b2 --draw 1 [--physics JSON]

`truth`: steps the calibration bench's dragging truth collapsed (`risk_calibration.py` shelves,
base seed 11, exact faces), each run on the truth's own shelf, masses and physics three ways: as
the truth pulls (`ride`: height free), as the worlds' `drag` pulls (`pull_hold`), and lifting.
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

TRUTH_CASES = (("structured", 12, "b10", ()), ("structured", 12, "b8", ()), ("structured", 13, "b8", ()),
               ("bridge", 13, "b6", ()), ("bridge", 11, "b6", ()), ("proud", 12, "b7", ()),
               ("unstructured", 12, "b5", ("b7",)), ("bridge", 12, "b9", ("b11",)))


def _watch(seen: dict):
    """Hook PullTrial's step to record, in `seen`, the downward push of the pulled box on the boxes
    below it at each step (`presses`, N; `press` the largest) and each other box's peak move
    (`peak`, m); returns the original step, to put back."""
    from shelfpick.planning import pull as pull_module
    from shelfpick.planning.geometry3 import dist

    step = pull_module.PullTrial._one_step

    def watched(self):
        out = step(self)
        press = sum(c[9] for c in self.p.getContactPoints(bodyA=self.body)
                    if c[7][2] > 0.5 and c[2] in self.body_box)
        seen["press"] = max(seen["press"], press)
        seen.setdefault("presses", []).append(press)
        for k, ob in enumerate(self.monitor.bodies):
            b = self.monitor.others[k]
            seen["peak"][b] = max(seen["peak"].get(b, 0.0),
                                  dist(self.p.getBasePositionAndOrientation(ob)[0], self.monitor.start[k][0]))
        return out

    pull_module.PullTrial._one_step = watched
    return step


def demo(box: str, worlds: int, overrides: dict, run_out: bool, pull_modes: tuple[str, ...] | None = None) -> None:
    from shelfpick.perception.scene import Scene
    from shelfpick.planning import pull as pull_module
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.sample_worlds import SampleWorlds
    from shelfpick.planning.uncertainty import Uncertainty, trial_seed

    scene = Scene.load(ROOT / "static" / "demo" / "demo-small-6.json").hide_depths()
    seen: dict = {}
    step = _watch(seen)
    cfg = PhysicsConfig().replace(**overrides).for_prediction()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = Uncertainty() if pull_modes is None else Uncertainty(pull_modes=pull_modes)
        sw = SampleWorlds(scene, 0, cfg, list(range(worlds)), model)
    failed = 0
    try:
        for i in range(worlds):
            seen.update(press=0.0, peak={})
            sim = sw.sims[i]
            c = sim.config
            if run_out:
                sim.restore(sw.state(i, frozenset()))
                r = sim.remove(box, seed=trial_seed(sw.seed, i, frozenset(), box), stop_on_collapse=False,
                               local=sw.local)
            else:
                r = sw.pull(i, frozenset(), box)
            if not (r.collapsed or not r.extracted):
                continue
            failed += 1
            mass = {b.id: round(b.mass, 2) for b in sim.scene.boxes}
            mode = "lift" if c.pull_lift > 0 else ("drag" if c.pull_hold else "ride")
            print(json.dumps({"world": i, "mode": mode, "force_limit_n": round(c.pull_force), "friction":
                              round(c.lateral_friction, 2), "masses_kg": mass,
                              "press_n": round(seen["press"]), "weight_n": round(mass[box] * c.gravity),
                              "collapsed": {b: {"end_mm": round(r.displacement[b] * 1000, 1),
                                                "end_deg": round(r.rotation[b], 1),
                                                "peak_mm": round(seen["peak"].get(b, 0.0) * 1000, 1)}
                                            for b in r.collapsed}, "note": r.note}))
    finally:
        sw.close()
        pull_module.PullTrial._one_step = step
    print(f"{failed}/{worlds} worlds fail pulling {box}")


def truth(overrides: dict) -> None:
    from benchmarks.risk_calibration import _truth_model
    from shelfpick.planning.bench import derive_seed, true_world
    from shelfpick.planning.execute import execute_plan
    from shelfpick.planning.shelves import generate

    for kind, seed, box, removed in TRUTH_CASES:
        name = f"{kind}-{seed}"
        shelf, physics, _ = true_world(generate(kind, seed, None), _truth_model("drag", 0.0, derive_seed(11, name, "lift")),
                                       derive_seed(11, name, "truth"))
        physics = physics.replace(**overrides)
        out = {}
        for how, cfg in (("truth (ride)", physics), ("drag", physics.replace(pull_hold=True)),
                         ("lift", physics.replace(pull_lift=0.006))):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                st = execute_plan(shelf, list(removed) + [box], seed=5, config=cfg).steps[-1]
            out[how] = {"collapsed": list(st.collapsed), "most_moved_mm": round(max(st.displacement.values()) * 1000)}
        print(json.dumps({"shelf": name, "pull": box, "after": list(removed), **out}))


def column_moments(scene, box: str, below: Sequence[str], friction: float, gravity: float) -> dict:
    """Coulomb's estimate for dragging `box` off the column `below` (top first) with its whole weight
    on it: the friction's moment about the lowest box's front bottom edge (Bullet's contact friction
    is the product of the two bodies', here `friction` squared) against the column's restoring one."""
    boxes = {b.id: b for b in scene.boxes}
    low, under = boxes[below[-1]], boxes[below[0]]
    pivot = low.position[1] - low.size[1] / 2
    lever = under.position[2] + under.size[2] / 2 - (low.position[2] - low.size[2] / 2)
    tipping = friction ** 2 * boxes[box].mass * gravity * lever
    restoring = sum(boxes[b].mass * gravity * (boxes[b].position[1] - pivot) for b in (box, *below))
    return {"tipping_nm": round(tipping, 2), "restoring_nm": round(restoring, 2)}


def pinned(shelf: str, box: str, below: Sequence[str], draw: int, seeds: int, overrides: dict) -> None:
    from dataclasses import replace

    from benchmarks import world_ablation as wa
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.sim import ShelfSim
    from shelfpick.planning.uncertainty import draw_config

    seed = shelf.rsplit("-", 1)[1]
    truth = wa.truth_of(shelf)
    masses = wa.masses_of(truth.boxes, int(seed), draw, (0.5, 3.0))
    scene = replace(truth, boxes=tuple(replace(b, mass=m) for b, m in zip(truth.boxes, masses)))
    cfg = draw_config(PhysicsConfig().replace(**overrides).for_prediction(), int(seed) + draw, 0, wa.pinned_model())
    weight = dict(zip(truth.ids, masses))[box] * cfg.gravity
    print(json.dumps({"shelf": shelf, "pull": box, "draw": draw, **column_moments(
        scene, box, below, cfg.lateral_friction, cfg.gravity)}))
    seen: dict = {}
    step = _watch(seen)
    try:
        for s in range(seeds):
            seen.update(press=0.0, presses=[], peak={})
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                with ShelfSim(scene, cfg) as sim:
                    r = sim.remove(box, seed=s)
            start = seen["presses"][:12]        # the first 0.1 s of the pull
            print(json.dumps({"pull_seed": s, "collapsed": {b: f"{r.displacement[b] * 100:.0f} cm" for b in r.collapsed},
                              "press_at_start_weights": round(sum(start) / len(start) / weight, 2),
                              "press_peak_weights": round(seen["press"] / weight, 1)}))
    finally:
        from shelfpick.planning import pull as pull_module
        pull_module.PullTrial._one_step = step


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("demo", "truth", "pinned"))
    ap.add_argument("--box", default="b4")
    ap.add_argument("--shelf", default="structured-43003", help="pinned: a planning.shelves kind-seed")
    ap.add_argument("--below", default="b8,b5,b2", help="pinned: the column under --box, top first")
    ap.add_argument("--draw", type=int, default=1, help="pinned: world_ablation's mass draw")
    ap.add_argument("--seeds", type=int, default=8, help="pinned: pull seeds (the vibration) to run")
    ap.add_argument("--worlds", type=int, default=40)
    ap.add_argument("--physics", default="{}", help="PhysicsConfig overrides as JSON")
    ap.add_argument("--run-out", action="store_true", help="run every trial to its end")
    ap.add_argument("--pull-modes", default=None, help="the worlds' pull modes (default lift,drag)")
    a = ap.parse_args(argv)
    overrides = json.loads(a.physics)
    if a.what == "demo":
        demo(a.box, a.worlds, overrides, a.run_out, tuple(a.pull_modes.split(",")) if a.pull_modes else None)
    elif a.what == "pinned":
        pinned(a.shelf, a.box, a.below.split(","), a.draw, a.seeds, overrides)
    else:
        truth(overrides)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
