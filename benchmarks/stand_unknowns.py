"""Which unknown makes a shelf "not standing as seen" (issue 32): its draws counted under other priors.

A shelf that stands where it was seen but not in our sample worlds is a false report, and every
plan on it is declared unsafe. For one scene file, `--draws` draws are built as `shelfpick plan`
builds them (`planning.sample_worlds.build_sample`: every redraw tried, no `known` shortcut) under
the cell's default prior and under variants that each take one unknown away or narrow it; the
count of draws that stand says which unknown the failure comes from.

    .venv/bin/python benchmarks/stand_unknowns.py SCENE.json [--draws 10] [--seed 0]
    .venv/bin/python benchmarks/stand_unknowns.py s19 --noise 0     # the judge's shelf as its camera sees it

(docs/results/risk-gate.md, "Session 54": the judge's s19 at exact faces stands in 4 of 10 draws,
in 10 of 10 with masses of 1-2 kg.)
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.stand_check import judge_view  # noqa: E402
from shelfpick.planning.uncertainty import Uncertainty  # noqa: E402

VARIANTS: dict[str, Uncertainty] = {
    "default": Uncertainty(),
    "no face error": replace(Uncertainty(), face_error=0.0),
    "masses 1-2 kg": replace(Uncertainty(), mass=(1.0, 2.0)),
    "friction 0.9": replace(Uncertainty(), friction=(0.9, 0.9)),
    "no face error, masses 1-2 kg": replace(Uncertainty(), face_error=0.0, mass=(1.0, 2.0)),
}


def standing_draws(doc: dict, model: Uncertainty, draws: int, seed: int,
                   origin: str = "scene") -> tuple[int, int, dict[str, int]]:
    """(draws that stand, draws that stood at their first attempt, box -> draws it did not stand in)."""
    from shelfpick.perception.scene import Scene
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.sample_worlds import build_sample, depth_ranges

    scene = Scene.from_json(doc, origin)
    config = PhysicsConfig().for_prediction()    # the Predictor's worlds, as `shelfpick plan` builds them
    ranges = None if scene.depth_known else depth_ranges(scene, config)
    stood = first = 0
    fell: dict[str, int] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for k in range(draws):
            d = build_sample(scene, seed, k, config, ranges, model)
            try:
                stood += d.stands
                first += d.stands and not d.rejected
                for b in d.off if not d.stands else ():
                    fell[b] = fell.get(b, 0) + 1
            finally:
                d.sim.close()
    return stood, first, fell


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scene", help="a scene file, or the name of one of the judge's shelves (s00..u19)")
    ap.add_argument("--draws", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", type=float, default=0.0, help="a judge's shelf: its camera's face error, m")
    ap.add_argument("--judge", default=str(ROOT.parent / "shared" / "judge"))
    a = ap.parse_args(argv)
    if Path(a.scene).is_file():
        doc, what = json.loads(Path(a.scene).read_text()), a.scene
    elif (Path(a.judge) / "scenes" / f"{a.scene}.json").is_file():
        doc, what = judge_view(Path(a.judge), a.scene, a.noise), f"the judge's {a.scene} at {a.noise * 100:g} cm"
    else:
        print(f"stand_unknowns: scene: {a.scene!r} is no file and no shelf in {a.judge}/scenes", file=sys.stderr)
        return 2
    print(f"{what}: draws that stand as seen, of {a.draws} (seed {a.seed})")
    print("| prior | stand | at the first attempt | boxes that did not stand (draws) |")
    print("|---|---:|---:|---|")
    for name, model in VARIANTS.items():
        stood, first, fell = standing_draws(doc, model, a.draws, a.seed, what)
        boxes = ", ".join(f"{b} ({n})" for b, n in sorted(fell.items(), key=lambda kv: -kv[1])) or "-"
        print(f"| {name} | {stood} | {first} | {boxes} |", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
