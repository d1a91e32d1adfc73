"""The gate a plan passes before anyone is asked to approve it: a calibrated chance of collapse.

The search decides with its sample worlds (ten by default). The gate asks the whole plan of OTHER
worlds, the ones after them: the search chose the plan because it held in its own worlds, so
asked there it looks safer than it is (on our shelves, against the judge's engines, the plans the
search's worlds called safe failed in 12.5% of the reference's mass draws, those fresh worlds
called safe in 5.6%: docs/results/risk-gate.md, "The gate asks worlds the search never saw"). It
counts the worlds in which any step failed and turns that count into a calibrated probability with
an interval (`planning.calibration`). Where the interval straddles the cell's `max_plan_risk`, it
asks `step` more worlds at a time (the worlds a Predictor of that many samples has: the same answer
for every worker count and call order) until it no longer does, or `max_worlds` are spent: few
worlds for clear plans, more for borderline ones. A plan is safe when the upper end of the interval
is below the threshold.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

from shelfpick.planning.calibration import Calibration, plan_failures
from shelfpick.planning.plan import StepPrediction
from shelfpick.planning.step_result import StepResult


def world_failed(r: StepResult) -> bool:
    """A world in which this step went wrong: another box collapsed, or the box would not come out."""
    return bool(r.collapsed) or r.note.startswith("stuck")


@dataclass(frozen=True)
class GateResult:
    """What the gate found: the per-step predictions over the worlds it used, and the plan's risk."""

    predicted: tuple[StepPrediction, ...]
    failed: int                 # worlds in which some step failed
    worlds: int
    probability: float          # calibrated chance that the plan collapses
    low: float
    high: float
    max_plan_risk: float

    @property
    def safe(self) -> bool:
        return self.high < self.max_plan_risk

    def to_json(self) -> dict[str, Any]:
        return {"probability": round(self.probability, 4), "low": round(self.low, 4),
                "high": round(self.high, 4), "failed_worlds": self.failed, "worlds": self.worlds,
                "max_plan_risk": self.max_plan_risk}


def gate(predictor: Any, sequence: Sequence[str], stands: bool, calibration: Calibration,
         max_plan_risk: float, first: int, max_worlds: int, step: int = 10, skip: int = 0) -> GateResult:
    """Ask `sequence` of `first` worlds after the first `skip` (the search's), then `step` more at a
    time while the calibrated interval straddles `max_plan_risk`, up to `max_worlds`
    (`predictor`: a `planning.predict.Predictor`). A shelf with nothing drawn has one world: it is asked."""
    n = max(1, first)
    while True:
        runs = [rs[skip:] for rs in predictor.plan_results(sequence, skip + n)]
        got = min((len(r) for r in runs), default=0)
        if skip and got == 0:
            skip = 0
            continue
        k, _ = plan_failures([[world_failed(r) for r in rs] for rs in runs])
        if got < n or n >= max_worlds or calibration.decided(k, n, max_plan_risk, stands):
            break          # (fewer than asked: a known shelf with nothing drawn has one world)
        n = min(max_worlds, n + step)
    n = got
    lo, hi = calibration.interval(k, n, stands)
    predicted = tuple(predictor.aggregate(b, rs) for b, rs in zip(sequence, runs))
    return GateResult(predicted, k, n, calibration.probability(k, n, stands), lo, hi, max_plan_risk)
