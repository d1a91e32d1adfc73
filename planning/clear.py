"""Physics-aware clearing search (the method's Algorithm 2), physics-free.

Visit the remaining boxes in a fixed order (top-down); pull the first box whose
predicted risk is at or under the threshold, then visit again from the top (a box
skipped above may be safe now). When no box is safe the least risky box is pulled
anyway (the plan becomes ``safe=False``; a higher box whose risk the samples
cannot tell from the least is preferred): every step removes a box, so the search
ends after n steps and at most n*(n+1)/2 distinct oracle calls.
"""
from __future__ import annotations

from typing import Callable, Iterable

from shelfpick.perception.scene import Scene
from shelfpick.planning.extract import CountingOracle, Oracle, SearchResult, _Deadline
from shelfpick.planning.plan import StepPrediction
from shelfpick.planning.resolution import prefer, resolution
from shelfpick.planning.shorten import Screen, alternative


def visit_order(scene: Scene) -> tuple[str, ...]:
    """Top-down, then front first, then left to right: the boxes a person would try first.

    Heights are compared to the millimetre so settling jitter does not
    reorder boxes that stand level.
    """
    def key(b):
        return (-round(b.top_z, 3), round(b.front_center[1], 3), round(b.position[0], 3), b.id)
    return tuple(b.id for b in sorted(scene.boxes, key=key))


def sampling_error(risk: float, samples: int) -> float:
    """Two standard errors of a risk estimated from `samples` worlds (a risk of 0 counts as 1/samples):
    risks closer than this are the same risk as far as `samples` worlds can tell."""
    return 2.0 * resolution(min(max(risk, 1.0 / samples), 1.0), samples)


def search_clear(ids: Iterable[str], trial: Oracle, risk: float = 0.0,
                 deadline: float | None = None, *, screen: Oracle | None = None,
                 least_risky: Callable[[frozenset[str], list[str]], str] | None = None,
                 samples: int | None = None) -> SearchResult:
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
        for i, box in enumerate(pending):
            pred = (screen or oracle)(removed, box)
            if pred.risk <= risk or clock.passed():
                take(box, oracle(removed, box) if screen is not None else pred)
                progressed = True
                # look again from the top: a box skipped above may be safe now
                skipped += [(b, pred) for b in pending[i + 1:]]
                break
            skipped.append((box, pred))
        if skipped and not progressed:
            # Nothing came out this pass, so every prediction is for the current
            # state: pull the least risky box (first in visiting order on a tie).
            if least_risky is not None:
                box = least_risky(removed, [b for b, _ in skipped])
            else:
                box = min(skipped, key=lambda bp: bp[1].risk)[0]
            if samples:
                box = _first_alike(box, [b for b, _ in skipped], removed, oracle, samples)
            take(box, oracle(removed, box))
            skipped = [(b, p) for b, p in skipped if b != box]
        pending = [b for b, _ in skipped]

    safe = all(p.risk <= risk for p in preds)
    return SearchResult(tuple(seq), tuple(preds), safe, oracle.calls, clock.hit)


def _first_alike(best: str, boxes: list[str], removed: frozenset[str], oracle: CountingOracle,
                 samples: int) -> str:
    """The first of `boxes` (visiting order) whose risk is within sampling error of `best`'s."""
    floor = oracle(removed, best).risk
    margin = sampling_error(floor, samples)
    for box in boxes:
        if box == best:
            return best
        if oracle(removed, box).risk <= floor + margin + 1e-9:
            return box
    return best


def prefer_baseline(result: SearchResult, baseline: Iterable[str], oracle: Oracle, risk: float = 0.0,
                    *, screen: Screen | None = None, worlds: int | None = None) -> SearchResult:
    """The baseline's order (highest first) instead of an unsafe clearance plan unless the physics
    predicts it a lower chance that no step collapses by more than the `worlds` sample worlds can
    resolve (`resolution.resolution`; without `worlds`, only when it is predicted better): the
    search must never hand the operator a plan it cannot tell from the order a person would use,
    and where it cannot, the person's order does not pull a box from under a load. A safe plan is
    kept as it is."""
    if result.safe:
        return result
    slack = resolution(result.success_prob, worlds)
    return prefer(alternative(result, tuple(baseline), 0, oracle, risk, screen, slack), result, slack)
