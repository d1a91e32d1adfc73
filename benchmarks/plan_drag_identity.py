#!/usr/bin/env python3
"""Experiment (issue 32): `shelfpick` as a cell whose gripper drags and whose stock weighs 0.5-3 kg,
with the share of failing sample worlds taken as the chance itself (no calibration map).

Not a product setting: `shelfpick plan --cell` gives a drag cell the drag calibration. This asks
what the gate says when the worlds' priors are those the independent judge's README states for
its gripper and stock. Use it as the judge's `--shelfpick`:

    PATH=$PWD/.venv/bin:$PATH .venv/bin/python ../shared/judge/evaluate.py \
        --shelfpick benchmarks/plan_drag_identity.py --noise 0
"""
import os
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

if __name__ == "__main__":   # the plan's worker processes are spawned: they import this file again
    from shelfpick.console.cli import main
    from shelfpick.planning import cmd_plan, planner
    from shelfpick.planning.calibration import Calibration
    from shelfpick.planning.priors import CellPriors

    default_model = cmd_plan._model

    def drag_model(args, priors=None):
        base = default_model(args, priors)
        return CellPriors(mass=(0.5, 3.0), pull_modes=("drag",)).model(base)

    cmd_plan._model = drag_model
    planner.calibration_for = lambda pulls: Calibration(fitted_on="identity (experiment)")
    sys.exit(main(sys.argv[1:]))
