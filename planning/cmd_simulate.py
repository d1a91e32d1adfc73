"""`shelfpick simulate SCENE PLAN`: execute a plan on a scene taken as ground truth."""
from __future__ import annotations

import argparse
import json
import logging
import warnings

from shelfpick.perception.errors import FormatError

log = logging.getLogger(__name__)

EXIT_PLAN_FAILED = 3  # the plan did not hold: something collapsed or the target did not come out (docs/cli.md)

HELP = "execute a plan on a scene (taken as ground truth) and print a JSON verdict; exit 3 if the plan does not hold"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="scene file (shelfpick.scene/1), the true shelf")
    parser.add_argument("plan", help="plan file (shelfpick.plan/1)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the gripper's vibration (default 0)")
    parser.add_argument("--out", default=None, help="also write the verdict to this file")
    parser.add_argument("--frames", action="store_true",
                        help="include the recorded box poses (~30 fps) in the verdict")


def run(args: argparse.Namespace) -> int:
    from shelfpick.perception.scene import Scene, output_path, write_json
    from shelfpick.planning.execute import execute_plan
    from shelfpick.planning.plan import Plan, scene_hash

    from shelfpick.planning.cmd_plan import SEEDS, check_int

    check_int(args.seed, "--seed", SEEDS, "a seed")
    if args.out:
        output_path(args.out, "--out")     # before the simulation: never onto a device, FIFO or folder
    scene = Scene.load(args.scene)
    plan = Plan.load(args.plan)
    plan.check_against(scene.ids, origin=str(args.plan))
    made_for = plan.provenance.get("scene_hash")
    if made_for and made_for != scene_hash(scene):
        log.info("the plan was made for another scene (hash %s, this one %s): running it on this one as the truth",
                 made_for, scene_hash(scene))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        execution = execute_plan(scene, plan.sequence, seed=args.seed, record=args.frames)
    for w in caught:
        log.warning("%s", w.message)
    log.debug("%d step(s) in %.2f s; repairs: %s", len(execution.steps), execution.wall_s,
              "; ".join(execution.repairs) or "none")
    doc = execution.to_json(frames=args.frames)
    doc["scene"] = str(args.scene)
    doc["plan"] = str(args.plan)
    doc["task"] = plan.task
    doc["target"] = plan.target
    if args.out:
        try:
            write_json(args.out, doc, "--out")
        except OSError as exc:
            raise FormatError(args.out, "--out", f"cannot write the verdict ({exc.strerror or exc})") from None
    print(json.dumps(doc, indent=2))
    if not execution.ok:
        step = execution.failed_step
        log.warning("the plan did not hold%s (exit %d)", "" if step is None else f" at step {step + 1}",
                    EXIT_PLAN_FAILED)
        return EXIT_PLAN_FAILED
    return 0
