"""Physics-aware clearing search (the method's Algorithm 2), physics-free.

Visit the remaining boxes in a fixed order; pull every box whose predicted
risk is at or under the threshold, skip the others, and revisit the skipped
ones in the next pass until the shelf is empty. A pass that removes nothing
would loop forever, so then the least risky box is pulled anyway (the plan
becomes ``safe=False``): every pass removes at least one box, so the search
ends after at most n passes and n*(n+1)/2 oracle calls.
"""
from __future__ import annotations

from typing import Callable, Iterable

from perception.scene import Scene
from planning.extract import CountingOracle, Oracle, SearchResult, _Deadline
from planning.plan import StepPrediction


def visit_order(scene: Scene) -> tuple[str, ...]:
    """Top-down, then front first, then left to right: the boxes a person would try first.

    Heights are compared to the millimetre so settling jitter does not
    reorder boxes that stand level.
    """
    def key(b):
        return (-round(b.top_z, 3), round(b.front_center[1], 3), round(b.position[0], 3), b.id)
    return tuple(b.id for b in sorted(scene.boxes, key=key))


def search_clear(ids: Iterable[str], trial: Oracle, risk: float = 0.0,
                 deadline: float | None = None, *, screen: Oracle | None = None,
                 least_risky: Callable[[frozenset[str], list[str]], str] | None = None) -> SearchResult:
    """Plan the removal of every box in ``ids`` (visited in the given order).

    After ``deadline`` (a ``time.monotonic()`` instant) no box is skipped any
    more: the rest are pulled in order, still each with its prediction.

    Optional fast path (``Predictor.screen`` / ``Predictor.least_risky``), same
    plan as without it: ``screen(removed, box)`` may stop sampling a box once it
    can no longer be safe (its risk is then a lower bound, but a safe answer is
    exact), and ``least_risky(removed, boxes)`` picks the least risky box (first
    in the given order on a tie) sampling only as far as that takes. The plan
    records the full ``trial`` prediction of every step taken.
    """
    pending = list(dict.fromkeys(ids))
    oracle = trial if isinstance(trial, CountingOracle) else CountingOracle(trial)
    clock = _Deadline(deadline)
    removed: frozenset[str] = frozenset()
    seq: list[str] = []
    preds: list[StepPrediction] = []

    def take(box: str, pred: StepPrediction) -> None:
        nonlocal removed
        seq.append(box)
        preds.append(pred)
        removed = removed | {box}

    while pending:
        skipped: list[tuple[str, StepPrediction]] = []
        progressed = False
        for box in pending:
            pred = (screen or oracle)(removed, box)
            if pred.risk <= risk or clock.passed():
                take(box, oracle(removed, box) if screen is not None else pred)
                progressed = True
            else:
                skipped.append((box, pred))
        if skipped and not progressed:
            # Nothing came out this pass, so every prediction is for the current
            # state: pull the least risky box (first in visiting order on a tie).
            if least_risky is not None:
                box = least_risky(removed, [b for b, _ in skipped])
            else:
                box = min(skipped, key=lambda bp: bp[1].risk)[0]
            take(box, oracle(removed, box))
            skipped = [(b, p) for b, p in skipped if b != box]
        pending = [b for b, _ in skipped]

    safe = all(p.risk <= risk for p in preds)
    return SearchResult(tuple(seq), tuple(preds), safe, oracle.calls, clock.hit)
