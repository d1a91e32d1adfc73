"""`shelfpick bench SCENES_DIR`: every box of every scene is the target once; both planners plan on
what a camera gives (front faces with perception error) and their plans run on a truth that differs
(true masses, friction, another pull): serial, local workers or Ray; resumable."""
from __future__ import annotations

import argparse
import logging
import math

from shelfpick.perception.errors import FormatError

log = logging.getLogger(__name__)

HELP = "benchmark the planners on a folder of scenes (serial, --workers N or --ray; resumable)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scenes", help="folder of scene files (shelfpick.scene/1), e.g. from `shelfpick scenes`")
    parser.add_argument("--planners", default="physics,heuristic", help="comma separated (default physics,heuristic)")
    parser.add_argument("--samples", type=int, default=10, help="depth samples per prediction (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    parser.add_argument("--out", default="bench-out", help="output folder (default bench-out); rerun to resume")
    parser.add_argument("--workers", type=int, default=1, help="local worker processes (default 1: serial)")
    parser.add_argument("--ray", default=None, metavar="auto|local|ADDRESS",
                        help="run on Ray: 'auto' (a running cluster), 'local' (start one here) or HOST:PORT")
    parser.add_argument("--limit", type=int, default=None, help="only the first K scenes (by file name)")
    parser.add_argument("--exhaustive-max-boxes", type=int, default=8,
                        help="exhaustive search over removal orders on scenes up to this size (default 8; 0: off)")
    parser.add_argument("--robot-time", type=float, default=12.5, help="robot seconds per removed box (default 12.5)")
    parser.add_argument("--truth", choices=("perturbed", "nominal"), default="perturbed",
                        help="perturbed (default): the planner sees front faces with perception error, the plan "
                             "runs on true masses, friction and another pull; nominal: the planner's own world "
                             "with depths hidden (flatters the planner)")
    parser.add_argument("--noise", type=float, default=0.01,
                        help="perception error on each front face's centre and size, m (default 0.01; perturbed only)")
    parser.add_argument("--no-catalogue", action="store_true",
                        help="the planner does not take a face of a stock box type to have that type's depth")
    parser.add_argument("--shared-predictor", action="store_true",
                        help="one Predictor per scene for all its targets (faster; planning times then "
                             "exclude its build and reuse cached trials)")


def run(args: argparse.Namespace) -> int:
    from shelfpick.planning.bench import BenchConfig, TruthModel, run_bench, to_markdown

    planners = tuple(p.strip() for p in args.planners.split(",") if p.strip())
    for p in planners:
        if p not in ("physics", "heuristic"):
            raise FormatError("--planners", "", f"unknown planner {p!r}; expected physics and/or heuristic")
    if not planners or len(set(planners)) != len(planners):
        raise FormatError("--planners", "", f"expected distinct planner names, got {args.planners!r}")
    if args.samples < 1:
        raise FormatError("--samples", "", f"expected a positive number, got {args.samples!r}")
    if args.workers < 1:
        raise FormatError("--workers", "", f"expected a positive number, got {args.workers!r}")
    if args.limit is not None and args.limit < 1:
        raise FormatError("--limit", "", f"expected a positive number, got {args.limit!r}")
    if not math.isfinite(args.robot_time) or args.robot_time <= 0:
        raise FormatError("--robot-time", "", f"expected a positive number of seconds, got {args.robot_time!r}")
    if not math.isfinite(args.noise) or not 0.0 <= args.noise <= 0.1:
        raise FormatError("--noise", "", f"expected metres in [0, 0.1], got {args.noise!r}")
    truth = TruthModel(noise=args.noise) if args.truth == "perturbed" else None
    config = BenchConfig(planners, args.samples, args.seed, max(0, args.exhaustive_max_boxes), args.robot_time,
                         shared_predictor=args.shared_predictor, truth=truth,
                         catalogue=not args.no_catalogue)
    summary = run_bench(args.scenes, args.out, config, workers=args.workers, ray_address=args.ray,
                        limit=args.limit)
    print(to_markdown(summary), end="")
    log.info("wrote %s/results.md, results.json, results.png, records.jsonl", args.out)
    return 0
