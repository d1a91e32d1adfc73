"""Drop the removals an extraction plan does not need.

Algorithm 1 clears blockers greedily: it pulls the first box a failed pull
moved, then tries the target again. A blocker that was pulled but did not make
the target safe stays in the plan, so the plan can move more boxes than it must
(a box moved is a chance of a collapse on the real shelf, and time). This pass
tries the plan without each blocker in turn, last first, and keeps the shorter
plan when the physics predicts it at least as well: every step still within the
risk threshold for a safe plan, a chance that no step collapses at least as high
for an unsafe one. It only asks the oracle; it never adds a box. `alternative`
(replay another order, bounded) serves the reorder and clearance passes too.
"""
from __future__ import annotations

from typing import Callable

from shelfpick.planning.extract import Oracle, SearchResult, success_prob
from shelfpick.planning.plan import StepPrediction


Screen = Callable[[frozenset[str], str, float], StepPrediction]


def bounded_replay(sequence: tuple[str, ...], start: int, removed: frozenset[str], oracle: Oracle,
            screen: Screen | None, limit: float | None, floor: float) -> list[StepPrediction] | None:
    """Predictions of `sequence[start:]` after `removed`, or None as soon as the candidate cannot
    be kept: a step over `limit` (a safe plan), or a chance of no collapse under `floor` (an
    unsafe plan; `floor` is that chance before `start`'s step, relative to it)."""
    out: list[StepPrediction] = []
    left = 1.0
    for box in sequence[start:]:
        if limit is not None:
            bound = limit
        else:   # the most this step may risk with every later step at risk 0
            bound = 1.0 - floor / left if left > 0 else -1.0
            if bound < -1e-12:
                return None
            bound = max(bound, 0.0)
        if screen is not None and screen(removed, box, bound).risk > bound + 1e-12:
            return None   # stopped early: the step alone already loses
        pred = oracle(removed, box)   # exact (a screen that passed sampled every world)
        if pred.risk > bound + 1e-12:
            return None
        out.append(pred)
        left *= 1.0 - pred.risk
        removed = removed | {box}
    return out


def alternative(result: SearchResult, cand: tuple[str, ...], start: int, oracle: Oracle, risk: float,
                screen: Screen | None = None, slack: float = 0.0) -> SearchResult | None:
    """`result` with `cand` from step `start` on (the steps before are the same boxes), or None
    when the physics predicts it worse: for a safe plan a step over `risk`, for an unsafe one a
    chance that no step collapses lower than the plan's by more than `slack` (the replay stops
    at the first step that decides it)."""
    preds = tuple(result.predicted)
    safe = all(p.risk <= risk for p in preds)
    # an unsafe plan: the candidate's later steps must keep prod(1 - r) >= the plan's - slack, so
    # the replay's per-step bounds already make a returned tail no worse than that
    floor = 0.0 if safe else max(0.0, success_prob(preds) - slack) / max(success_prob(preds[:start]), 1e-12)
    tail = bounded_replay(cand, start, frozenset(cand[:start]), oracle, screen, risk if safe else None, floor)
    return None if tail is None else result.replaced(cand, preds[:start] + tuple(tail), risk)


def shorten_extraction(result: SearchResult, oracle: Oracle, risk: float = 0.0, *,
                       screen: Screen | None = None,
                       passed: Callable[[], bool] = lambda: False) -> SearchResult:
    """`result` (an extraction plan, target last) without the blockers it does not need.

    ``screen(removed, box, bound)`` (optional, ``Predictor.screen``) is asked first with
    the most risk the step may carry for the candidate to be kept, and stops sampling
    as soon as it cannot; every kept step carries the full ``oracle`` prediction.
    ``passed()`` True stops the pass (the search's deadline).
    """
    out = result
    for i in range(len(result.sequence) - 2, -1, -1):
        if passed():
            break
        seq = out.sequence
        out = alternative(out, seq[:i] + seq[i + 1:], i, oracle, risk, screen) or out
    return result if out.sequence == tuple(result.sequence) else out
