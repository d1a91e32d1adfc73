"""shelfpick from Python, without the command line: a capture -> a scene -> a plan -> its outcome.

Renders a synthetic RGB-D capture of a demo shelf (stand-in for a camera), perceives it, plans
the extraction of one box with the physics-aware planner and, for comparison, the highest-first
baseline, then runs both plans on the true shelf. Needs the `perception` extra
(`pip install 'shelfpick[perception]'`); planning alone needs only the core.

    python examples/plan_from_python.py [--scene static/demo/demo-small-6.json] [--samples 4]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from shelfpick.perception.pipeline import perceive
from shelfpick.perception.render import render
from shelfpick.perception.scene import Scene
from shelfpick.planning.execute import execute_plan
from shelfpick.planning.planner import make_plan

DEMO = Path(__file__).resolve().parents[1] / "static" / "demo" / "demo-small-6.json"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scene", default=str(DEMO), help="the true shelf (shelfpick.scene/1)")
    p.add_argument("--samples", type=int, default=4, help="depth samples per prediction (default 4)")
    p.add_argument("--seed", type=int, default=0, help="seed of the render, the samples and the pulls")
    args = p.parse_args()

    truth = Scene.load(args.scene)
    capture = render(truth, seed=args.seed)              # a real camera: perception.capture.load_capture
    seen = perceive(capture).scene                        # front faces only: depth_known false
    # the box seen lowest in the middle: the one that most often has others on it
    target = min(seen.boxes, key=lambda b: (b.position[2], abs(b.position[0]))).id
    result = {"boxes_seen": len(seen.boxes), "boxes_true": len(truth.boxes), "target": target}
    for planner in ("physics", "heuristic"):
        plan = make_plan(seen, "extract", target, planner=planner, samples=args.samples, seed=args.seed)
        # the robot acts on the true shelf; perceived ids are matched to true boxes by position
        true_ids = [nearest(truth, seen.box(b).front_center) for b in plan.sequence]
        outcome = execute_plan(truth, true_ids, seed=args.seed)
        # "succeeded": every box came out and nothing collapsed. (The console says "held" for a robot
        # it stopped after a look that differed from the prediction: a word with that one meaning.)
        result[planner] = {"sequence": list(plan.sequence), "predicted_safe": plan.safe,
                           "succeeded": outcome.ok, "collapsed": outcome.collapsed}
    json.dump(result, sys.stdout, indent=2)
    sys.stdout.write("\n")
    return 0


def nearest(scene: Scene, point) -> str:
    """Id of the box whose front-face centre is nearest `point` (shelf frame)."""
    return min(scene.boxes, key=lambda b: sum((a - c) ** 2 for a, c in zip(b.front_center, point))).id


if __name__ == "__main__":
    sys.exit(main())
