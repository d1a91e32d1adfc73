"""Drop the removals an extraction plan does not need.

Algorithm 1 clears blockers greedily: it pulls the first box a failed pull
moved, then tries the target again. A blocker that was pulled but did not make
the target safe stays in the plan, so the plan can move more boxes than it must
(a box moved is a chance of a collapse on the real shelf, and time). This pass
tries the plan without each blocker in turn, last first, and keeps the shorter
plan when the physics predicts it at least as well: every step still within the
risk threshold for a safe plan, a chance that no step collapses at least as high
for an unsafe one. It only asks the oracle; it never adds a box.
"""
from __future__ import annotations

from typing import Callable

from planning.extract import Oracle, SearchResult, success_prob
from planning.plan import StepPrediction


def _replay(sequence: tuple[str, ...], start: int, removed: frozenset[str], ask: Oracle,
            limit: float | None) -> list[StepPrediction] | None:
    """Predictions of `sequence[start:]` after `removed`; None as soon as a step is over `limit`."""
    out: list[StepPrediction] = []
    for box in sequence[start:]:
        pred = ask(removed, box)
        if limit is not None and pred.risk > limit:
            return None
        out.append(pred)
        removed = removed | {box}
    return out


def shorten_extraction(result: SearchResult, oracle: Oracle, risk: float = 0.0, *,
                       screen: Oracle | None = None,
                       passed: Callable[[], bool] = lambda: False) -> SearchResult:
    """`result` (an extraction plan, target last) without the blockers it does not need.

    ``screen`` (optional) is asked first and may stop a candidate early; every kept
    step carries the full ``oracle`` prediction. ``passed()`` True stops the pass
    (the search's deadline).
    """
    seq, preds = tuple(result.sequence), tuple(result.predicted)
    safe = all(p.risk <= risk for p in preds)
    for i in range(len(seq) - 2, -1, -1):
        if passed() or i >= len(seq) - 1:
            continue
        cand = seq[:i] + seq[i + 1:]
        before = frozenset(seq[:i])
        if safe and screen is not None and _replay(cand, i, before, screen, risk) is None:
            continue
        tail = _replay(cand, i, before, oracle, risk if safe else None)
        if tail is None:
            continue
        new = preds[:i] + tuple(tail)
        if (all(p.risk <= risk for p in new) if safe
                else success_prob(new) >= success_prob(preds)):
            seq, preds = cand, new
    if len(seq) == len(result.sequence):
        return result
    return SearchResult(seq, preds, all(p.risk <= risk for p in preds), result.calls, result.timed_out)
