"""Physics-aware extraction search (the method's Algorithm 1), physics-free.

The search only sees an *oracle*: ``trial(removed, box) -> StepPrediction``
says what happens when ``box`` is pulled from the shelf once the boxes in
``removed`` are gone. The physics (``planning/predict.py``) provides the real
one; tests provide fake oracles built from a support graph. Each oracle call is
a batch of physics trials, so the search memoises calls and counts them.

Algorithm 1 with the additions the product needs:

* try the target; when its risk is above the threshold, recursively extract
  the first box that moved (``prediction.moved[0]``), then retry the target;
* cycle protection: a box already on the recursion stack is never recursed
  into again; the next moved box is tried instead;
* when the first collapser cannot itself be removed safely, the other moved
  boxes are tried (cheap improvement over the plain method);
* a depth bound and an optional deadline (``time.monotonic()`` instant);
* when no safe plan exists, the least risky plan found is returned with
  ``safe=False``. "Least risky" is judged by the chance that no step
  collapses, prod(1 - risk_i): at every dead end the search compares two
  complete plans, pulling the box now, or running the blocker sub-plan most
  likely to go well and then planning the box again from there, and keeps the
  likelier success. Greedy over blockers, not a global optimum.
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Callable, Iterable

from shelfpick.planning.plan import StepPrediction

Oracle = Callable[[frozenset[str], str], StepPrediction]


@dataclass(frozen=True)
class SearchResult:
    """A removal sequence, the prediction for every step, and how the search went."""

    sequence: tuple[str, ...]
    predicted: tuple[StepPrediction, ...]
    safe: bool
    calls: int = 0            # distinct oracle calls (physics trial batches)
    timed_out: bool = False   # the deadline cut the search short

    @property
    def risk(self) -> float:
        """Largest step risk of the plan (0 when every step is predicted still)."""
        return max((p.risk for p in self.predicted), default=0.0)

    @property
    def success_prob(self) -> float:
        """Predicted chance that no step collapses (steps taken as independent)."""
        return success_prob(self.predicted)

    def replaced(self, sequence: tuple[str, ...], predicted: tuple[StepPrediction, ...],
                 risk: float) -> "SearchResult":
        """Another plan found by the same search (its calls, its deadline), safe at `risk` or not."""
        return SearchResult(tuple(sequence), tuple(predicted), all(p.risk <= risk for p in predicted),
                            self.calls, self.timed_out)


def success_prob(predicted: Iterable[StepPrediction]) -> float:
    """prod(1 - risk) over the steps: how the fallback ranks unsafe plans."""
    out = 1.0
    for p in predicted:
        out *= 1.0 - p.risk
    return out


class CountingOracle:
    """Memoises an oracle by ``(removed, box)`` and counts the distinct calls."""

    def __init__(self, trial: Oracle):
        self._trial = trial
        self._cache: dict[tuple[frozenset[str], str], StepPrediction] = {}

    @property
    def calls(self) -> int:
        return len(self._cache)

    def has(self, key: tuple[frozenset[str], str]) -> bool:
        """Whether `key` was asked (its full prediction is held)."""
        return key in self._cache

    @property
    def keys(self) -> set[tuple[frozenset[str], str]]:
        """The distinct (removed, box) questions asked so far."""
        return set(self._cache)

    def __call__(self, removed: frozenset[str], box: str) -> StepPrediction:
        key = (frozenset(removed), box)
        hit = self._cache.get(key)
        if hit is None:
            hit = self._trial(key[0], box)
            self._cache[key] = hit
        return hit


class _Deadline:
    def __init__(self, deadline: float | None):
        self.deadline = deadline
        self.hit = False

    def passed(self) -> bool:
        if self.deadline is not None and time.monotonic() >= self.deadline:
            self.hit = True
        return self.hit


@dataclass(frozen=True)
class _Outcome:
    sequence: tuple[str, ...]
    predicted: tuple[StepPrediction, ...]
    start: frozenset[str] = frozenset()   # removed before its first step (names each step's question)

    def keys(self) -> list[tuple[frozenset[str], str]]:
        """The (removed, box) question of each step."""
        out, removed = [], self.start
        for box in self.sequence:
            out.append((removed, box))
            removed = removed | {box}
        return out

    @property
    def risk(self) -> float:
        return max((p.risk for p in self.predicted), default=0.0)

    @property
    def success(self) -> float:
        return success_prob(self.predicted)


Bounds = Callable[[frozenset[str], str], tuple[float, float]]


def search_extract(ids: Iterable[str], target: str, trial: Oracle, risk: float = 0.0,
                   max_depth: int | None = None, deadline: float | None = None, *,
                   screen: Oracle | None = None, bounds: Bounds | None = None,
                   more: Callable[[frozenset[str], str], object] | None = None) -> SearchResult:
    """Plan the removals that get ``target`` out with every step's risk <= ``risk``.

    ``ids`` are the boxes on the shelf; ``max_depth`` bounds the recursion
    (default: the number of boxes); ``deadline`` is a ``time.monotonic()``
    instant after which no further blocker is explored (the boxes still on
    the stack are then pulled as they are, so a plan always comes back).

    ``screen`` (optional, ``Predictor.screen``) answers "is this pull safe?" with
    as few depth samples as that takes: a safe answer covers every sample, an
    unsafe one stops at the first sample past the threshold, and its ``moved``
    boxes (the blockers tried next) come from the samples run so far. Every
    step of the returned plan, and every risk compared at a dead end, is the
    full ``trial`` prediction.

    ``bounds(removed, box)`` (optional, with ``screen``; ``Predictor.risk_interval``): the
    interval the full risk of a screened pull lies in, from the samples run so far, and
    ``more(removed, box)`` runs one more of its samples. A dead end then compares plans on those
    intervals, sampling the widest screened step one sample at a time until they decide; a pull
    is fully predicted only where that needs it or in the plan returned: the same plan (every
    decision is the exact one), fewer samples run.
    """
    present = tuple(ids)
    if target not in present:
        raise ValueError(f"target {target!r} is not among the boxes {present!r}")
    oracle = trial if isinstance(trial, CountingOracle) else CountingOracle(trial)
    depth_bound = len(present) if max_depth is None else max(0, int(max_depth))
    search = _ExtractSearch(oracle, screen, risk, depth_bound, _Deadline(deadline), frozenset(present),
                            bounds if screen is not None else None, more)
    out = search.complete(search.extract(target, frozenset(), ()))
    return SearchResult(out.sequence, out.predicted, out.risk <= risk, oracle.calls, search.clock.hit)


@dataclass
class _ExtractSearch:
    """The backtracking of `search_extract`: pull a box; if that is unsafe, first get out the
    boxes it would move (recursively), else compare pulling it now with the likeliest blocker plan."""

    oracle: CountingOracle
    screen: Oracle | None
    risk: float
    depth_bound: int
    clock: "_Deadline"
    known: frozenset[str]
    bounds: Bounds | None = None
    more: Callable[[frozenset[str], str], object] | None = None   # run one more sample of a pull

    # ---- plans whose unsafe steps may be screened only (`bounds`): exact wherever compared
    def _exact(self, key: tuple[frozenset[str], str]) -> bool:
        return self.bounds is None or self.oracle.has(key)

    def success_range(self, o: _Outcome) -> tuple[float, float]:
        """(lowest, highest) chance that no step of `o` collapses, whatever its unrun samples say;
        both are `o.success` once every step is fully predicted (the same products, in order)."""
        lo = hi = 1.0
        for key in o.keys():
            # a step asked in full since `o` was put together counts with its full prediction
            r_lo, r_hi = (self.oracle(*key).risk,) * 2 if self._exact(key) else self.bounds(*key)  # type: ignore[misc]
            lo *= 1.0 - r_hi
            hi *= 1.0 - r_lo
        return lo, hi

    def complete(self, o: _Outcome) -> _Outcome:
        """`o` with every step's full prediction (what the search without `bounds` holds)."""
        if self.bounds is None:
            return o
        return _Outcome(o.sequence, tuple(self.oracle(*k) for k in o.keys()), o.start)

    def greater(self, a: _Outcome, b: _Outcome, fa: float = 1.0, fb: float = 1.0) -> tuple[bool, _Outcome, _Outcome]:
        """Whether fa * a.success > fb * b.success, from the ranges when they decide it, else
        from full predictions; and `a`, `b` (completed where that was needed)."""
        if self.bounds is None or self.more is None:   # every step fully predicted: the plain comparison
            a, b = self.complete(a), self.complete(b)
            return fa * a.success > fb * b.success, a, b
        while True:
            a_lo, a_hi = self.success_range(a)
            b_lo, b_hi = self.success_range(b)
            if fa * a_lo > fb * b_hi:
                return True, a, b
            if fa * a_hi <= fb * b_lo:   # (always one of the two once every sample has run)
                return False, a, b
            # one more sample of the widest screened step (first of `a`, then of `b`, on a tie)
            open_ = [(k, self.bounds(*k)) for k in a.keys() + b.keys() if not self._exact(k)]  # type: ignore[misc]
            self.more(*max((hi - lo, -i, k) for i, (k, (lo, hi)) in enumerate(open_))[2])

    def _ask(self, removed: frozenset[str], box: str) -> StepPrediction:
        return self.screen(removed, box) if self.screen is not None else self.oracle(removed, box)

    def extract(self, box: str, removed: frozenset[str], stack: tuple[str, ...]) -> _Outcome:
        seq: list[str] = []
        preds: list[StepPrediction] = []
        cur = removed
        while True:
            pred = self._ask(cur, box)
            if pred.risk <= self.risk:
                full = self.oracle(cur, box) if self.screen is not None else pred
                return _Outcome((*seq, box), (*preds, full), removed)
            cleared, best = self._clear_blocker(box, cur, stack, pred)
            if cleared is not None:
                seq += cleared.sequence
                preds += cleared.predicted
                cur = cur | set(cleared.sequence)
                continue  # retry the box with its blocker gone
            return self._dead_end(box, removed, cur, stack, seq, preds, pred, best)

    def _clear_blocker(self, box: str, cur: frozenset[str], stack: tuple[str, ...],
                       pred: StepPrediction) -> tuple[_Outcome | None, _Outcome | None]:
        """(the first blocker plan that is safe, None) or (None, the blocker plan likeliest to go well)."""
        on_stack = set(stack) | {box}
        candidates = [m for m in dict.fromkeys(pred.moved)
                      if m in self.known and m not in cur and m not in on_stack]
        best: _Outcome | None = None
        if len(stack) < self.depth_bound:
            for m in candidates:
                if self.clock.passed():
                    break
                sub = self.extract(m, cur, (*stack, box))
                if sub.risk <= self.risk:   # (a step only screened is surely over the risk)
                    return sub, None
                if best is None:
                    best = sub
                    continue
                better, sub, best = self.greater(sub, best)
                if better:
                    best = sub
        return None, best

    def _dead_end(self, box: str, start: frozenset[str], cur: frozenset[str], stack: tuple[str, ...],
                  seq: list[str], preds: list[StepPrediction], pred: StepPrediction,
                  best: _Outcome | None) -> _Outcome:
        """No blocker comes out safely. Compare two complete plans: pull the box now, or run
        the blocker plan most likely to go well and then plan this box again from there;
        keep the likelier success. (With `bounds`, the pull now stays screened until a
        comparison or the plan returned needs its full prediction.)"""
        if self.screen is not None and self.bounds is None:
            pred = self.oracle(cur, box)  # the full prediction: risks are compared from here on
        now = _Outcome((*seq, box), (*preds, pred), start)
        if best is None:
            return now
        bet, best, now = self.greater(best, now, success_prob(preds), 1.0)
        if not bet:
            return now  # the blocker alone is already a worse bet than pulling now
        rest = self.extract(box, cur | set(best.sequence), stack)
        then = _Outcome((*seq, *best.sequence, *rest.sequence), (*preds, *best.predicted, *rest.predicted), start)
        better, then, now = self.greater(then, now)
        return then if better else now
