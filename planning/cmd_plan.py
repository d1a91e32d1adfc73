"""`shelfpick plan`: plan an extraction or a clearing for a scene file."""
from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import sys
import warnings
from dataclasses import replace
from typing import TYPE_CHECKING

from shelfpick.perception.errors import FormatError, SceneError

if TYPE_CHECKING:  # pragma: no cover
    from shelfpick.planning.plan import Plan
    from shelfpick.planning.priors import CellPriors
    from shelfpick.planning.uncertainty import Uncertainty

log = logging.getLogger(__name__)

HELP = "plan the removals that extract a box (or clear the shelf) without a collapse"
# every number option's bound (docs/cli.md "Bounds"), checked before anything is allocated; the cell
# file's [safety] section and `shelfpick console` take theirs from here
SAMPLES = (1, 1000)            # sample worlds per prediction: each one is a physics world in memory
VERIFY = (0, 1000)
WORKERS = (1, 256)
SEEDS = (0, 2**63 - 1)
BUDGET_S = 7 * 24 * 3600.0     # a week


def check_int(value: int, flag: str, bounds: tuple[int, int], what: str) -> None:
    """A FormatError naming the option unless lo <= value <= hi."""
    if not bounds[0] <= value <= bounds[1]:
        raise FormatError("", flag, f"expected {what} from {bounds[0]} to {bounds[1]}, got {value}")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="scene file (shelfpick.scene/1)")
    parser.add_argument("--task", choices=("extract", "clear"), default="extract",
                        help="extract one box (needs --target) or clear the shelf (default: extract)")
    parser.add_argument("--target", default=None, help="id of the box to extract")
    parser.add_argument("--planner", choices=("physics", "heuristic"), default="physics",
                        help="physics-aware search (default) or the highest-first baseline")
    parser.add_argument("--samples", type=int, default=10,
                        help="depth samples per prediction for boxes of unknown depth (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the depth samples and pulls (default 0)")
    parser.add_argument("--verify", type=int, default=30, metavar="N",
                        help="the plan found is asked of up to N more sample worlds, 10 at a time, while its "
                             "calibrated risk interval straddles --max-plan-risk (default 30; 0: only the "
                             "search's worlds)")
    parser.add_argument("--cell", default=None, metavar="CELL.toml",
                        help="the cell file whose [planning] section gives the sample worlds' masses, friction "
                             "and pull modes, and --max-plan-risk's default (other sections are not read; "
                             "docs/cli.md \"Cell file\")")
    parser.add_argument("--max-plan-risk", type=float, default=None, metavar="P",
                        help="highest acceptable calibrated chance that the plan collapses: the plan is safe "
                             "when the upper end of its interval is below it (default: the --cell file's "
                             "planning.max_plan_risk, else 0.05)")
    parser.add_argument("--risk", type=float, default=0.0,
                        help="highest acceptable collapse probability per step (default 0: no sample collapses)")
    parser.add_argument("--budget", type=float, default=None, metavar="SECONDS",
                        help="time budget of the physics search (default: none)")
    parser.add_argument("--workers", type=int, default=None,
                        help="processes over the sample worlds (default: 2 where the machine has 2 cores "
                             "or more, else 1; the same plan whatever the count)")
    parser.add_argument("--no-catalogue", action="store_true",
                        help="the stock is not the reference box types: a box's depth is drawn from the "
                             "shelf alone, never from the type its front face matches")
    parser.add_argument("--face-error", type=float, default=None, metavar="M",
                        help="the perceived faces' error in this cell, as a half-range in m: each world "
                             "moves every face by up to M in its plane and along its normal and changes its "
                             "width and height by up to M (default: 0.005 in its plane only; docs/cli.md)")
    parser.add_argument("--out", default=None, help="write the plan here (default: stdout)")


def _warn(msg: str) -> None:
    log.warning("%s", msg)


def _warn_about(plan: Plan, args: argparse.Namespace) -> None:
    for msg in plan_warnings(plan, args.budget, args.risk):
        _warn(msg)


def plan_warnings(plan: Plan, budget: float, risk: float) -> list[str]:
    """What the user must know before trusting the plan: a budget that ran out, a shelf that
    does not stand as seen, each reason the plan is not safe (doubted faces, unexplained matter,
    a calibrated chance not below the threshold: only those that hold), and the least
    risky plan's worst step. `budget`, `risk`: the options as given."""
    out: list[str] = []
    search = plan.extra.get("search", {})
    if search.get("timed_out"):
        out.append(f"the planning budget of {budget:g} s ran out; the plan is the best "
                   "found so far, not a complete search")
    check = plan.extra.get("scene_check", {})
    for prob in check.get("problems", []):
        who = f"box {prob['box']}" if prob.get("box") else "the scene"
        out.append(f"the shelf does not stand as observed: {who} {prob['what']}; no plan on it is safe")
    for why in (plan.extra.get("unexplained") or {}).get("touched", []):
        out.append(f"{why} (matter no perceived box explains); the plan is not safe")
    for why in (plan.extra.get("contradicted") or {}).get("touched", []):
        out.append(f"{why} (perception said its faces cannot all be right); the plan is not safe")
    gate = search.get("plan_risk")
    if not plan.safe and plan.predicted and isinstance(gate, dict) and gate["high"] >= gate["max_plan_risk"]:
        out.append(f"the plan's calibrated chance of a collapse is {gate['probability']:.3f} (up to {gate['high']:.3f}; "
                   f"it failed in {gate['failed_worlds']} of {gate['worlds']} sample worlds): not below the "
                   f"threshold {gate['max_plan_risk']:g}; it is not safe")
    if not plan.safe and plan.predicted:
        worst = max(range(len(plan.predicted)), key=lambda i: plan.predicted[i].risk)
        step = plan.predicted[worst]
        moved = ", ".join(step.moved) or "nothing named"
        out.append(f"no safe plan found; the least risky plan found has risk {plan.risk:.2f} (the share of sample "
                   f"worlds its worst step collapses or collides in, --risk {risk:g}; chance that nothing collapses "
                   f"{search.get('success_prob', 0):.2f}): step {worst + 1} (pull {step.box}) may move {moved}")
    return out


def _model(args: argparse.Namespace, priors: "CellPriors | None") -> "Uncertainty | None":
    """What the worlds draw, where the options or the cell change the default model (None: the default)."""
    from shelfpick.planning.uncertainty import Uncertainty

    if not args.no_catalogue and args.face_error is None and priors is None:
        return None
    model = Uncertainty(catalogue=()) if args.no_catalogue else Uncertainty()
    if args.face_error is not None:
        e = args.face_error
        model = replace(model, face_error=e, face_size_error=e, face_depth_error=e)
    return priors.model(model) if priors is not None else model


def read_cell_priors(path: str) -> tuple["CellPriors", dict]:
    """The priors of a cell file's [planning] section (`--cell`), checked as the console checks
    them (planning.priors), and the plan's record of the file (path and `section_hash` of the
    [planning] section as read); the file's other sections are the console's and are not read. A
    FormatError (one line: file, field, value) when the file cannot be read as a cell file
    (planning.cell_file), is of another format, or is wrong in [planning]."""
    from shelfpick.planning.cell_file import CELL_FORMAT, read_cell_toml
    from shelfpick.planning.priors import CellPriors

    doc = read_cell_toml(path, "--cell")
    if doc.get("format", CELL_FORMAT) != CELL_FORMAT:
        raise FormatError(path, "format", f"expected {CELL_FORMAT!r}, got {doc['format']!r}")
    if "planning" not in doc:
        _warn(f"{path} has no [planning] section: the sample worlds draw the default masses, friction "
              "and pull modes")
    section = doc.get("planning", {})
    priors = CellPriors.from_section(section, path)
    canonical = json.dumps(section, sort_keys=True, separators=(",", ":"), default=str)
    return priors, {"path": str(path), "section_hash": hashlib.sha256(canonical.encode()).hexdigest()[:16]}


def run(args: argparse.Namespace) -> int:
    from shelfpick.perception.scene import Scene, output_path
    from shelfpick.planning.planner import check_request, make_plan

    check_int(args.samples, "--samples", SAMPLES, "a positive integer")
    if not 0.0 <= args.risk <= 1.0:
        raise FormatError("", "--risk", f"expected a probability in [0, 1], got {args.risk}")
    check_int(args.verify, "--verify", VERIFY, "a number of sample worlds")
    from shelfpick.planning.calibration import DEFAULT_MAX_PLAN_RISK

    priors, cell = read_cell_priors(args.cell) if args.cell is not None else (None, None)
    if args.max_plan_risk is None:      # the flag wins over the cell, the cell over the default
        args.max_plan_risk = priors.max_plan_risk if priors is not None else DEFAULT_MAX_PLAN_RISK
    if not 0.0 < args.max_plan_risk <= 1.0:
        raise FormatError("", "--max-plan-risk", f"expected a probability in (0, 1], got {args.max_plan_risk}")
    check_int(args.seed, "--seed", SEEDS, "a seed")
    if args.workers is None:
        args.workers = 2 if (os.cpu_count() or 1) >= 2 else 1
    check_int(args.workers, "--workers", WORKERS, "a positive integer")
    if args.budget is not None and not 0 < args.budget <= BUDGET_S:
        raise FormatError("", "--budget", f"expected a positive number of seconds up to {BUDGET_S:g}, "
                          f"got {args.budget}")
    if args.face_error is not None and not 0.0 <= args.face_error <= 0.05:
        raise FormatError("", "--face-error", f"expected metres in [0, 0.05], got {args.face_error}")
    if args.out:
        output_path(args.out, "--out")     # before planning: never onto a device, FIFO or folder
    scene = Scene.load(args.scene)
    # refuse a bad request (unknown target, target for clear...) before any physics is built
    check_request(scene, args.task, args.target, args.planner, args.samples, args.risk, args.scene)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            plan = make_plan(scene, args.task, args.target, planner=args.planner, samples=args.samples,
                             seed=args.seed, risk=args.risk, budget_s=args.budget, origin=args.scene,
                             workers=args.workers, verify=args.verify, model=_model(args, priors),
                             max_plan_risk=args.max_plan_risk)
        except SceneError as exc:  # the physics refused the scene: say which file
            raise SceneError(f"{args.scene}: {exc}") from None
    plan = plan.with_provenance(scene, samples=args.samples, risk=args.risk, cell=cell)
    log.debug("scene %s: %d boxes, hash %s; %s planner, %d samples, seed %d, %d worker(s)", args.scene,
              len(scene.boxes), plan.provenance["scene_hash"], args.planner, args.samples, args.seed, args.workers)
    log.debug("timing: %s", ", ".join(f"{k} {v:.2f} s" for k, v in plan.timing.items()))
    for w in caught:
        _warn(str(w.message))
    _warn_about(plan, args)
    if args.out:
        try:
            plan.save(args.out)
        except OSError as exc:
            raise FormatError(args.out, "--out", f"cannot write the plan ({exc.strerror or exc})") from None
        log.info("%d step(s) %s; safe=%s; wrote %s", len(plan.sequence),
                 " -> ".join(plan.sequence) or "(none)", str(plan.safe).lower(), args.out)
    else:
        json.dump(plan.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    return 0
