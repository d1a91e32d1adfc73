"""Fake safety oracles for testing the planners without physics.

A *support graph* says which box rests on which: pulling ``Y`` makes every
box resting on ``Y`` collapse, and whatever rests on those, in breadth-first
order (the first collapser is the box directly on ``Y``). Each oracle counts
how often it was asked, so tests can check the search stays cheap.
"""
from __future__ import annotations

from typing import Callable, Mapping, Sequence

from shelfpick.planning.plan import StepPrediction


class SupportGraph:
    """``rests_on[x]`` = the boxes ``x`` rests on; ``prob`` = collapse probability of a move."""

    def __init__(self, rests_on: Mapping[str, Sequence[str]], ids: Sequence[str] | None = None,
                 prob: float = 1.0):
        self.rests_on = {k: tuple(v) for k, v in rests_on.items()}
        names = list(ids) if ids is not None else []
        for k, v in self.rests_on.items():
            for n in (k, *v):
                if n not in names:
                    names.append(n)
        self.ids = tuple(names)
        self.prob = prob
        self.asked: list[tuple[frozenset[str], str]] = []

    def on_top_of(self, y: str, present: set[str]) -> list[str]:
        return [x for x in self.ids if x in present and y in self.rests_on.get(x, ())]

    def __call__(self, removed: frozenset[str], box: str) -> StepPrediction:
        self.asked.append((removed, box))
        assert box not in removed, f"asked to pull {box!r} which is already gone"
        present = set(self.ids) - set(removed) - {box}
        moved: list[str] = []
        frontier = [box]
        while frontier:
            y = frontier.pop(0)
            for x in self.on_top_of(y, present):
                if x not in moved:
                    moved.append(x)
                    frontier.append(x)
        p = self.prob if moved else 0.0
        return StepPrediction(box, p, 0.0, tuple(moved))

    def safe(self, removed: frozenset[str], box: str) -> bool:
        return self(removed, box).risk == 0.0


def table_oracle(rules: Callable[[frozenset[str], str], tuple[float, tuple[str, ...]]]):
    """An oracle from a function ``(removed, box) -> (collapse_prob, moved)``, counting calls."""
    asked: list[tuple[frozenset[str], str]] = []

    def trial(removed: frozenset[str], box: str) -> StepPrediction:
        asked.append((removed, box))
        p, moved = rules(removed, box)
        return StepPrediction(box, p, 0.0, tuple(moved))

    trial.asked = asked  # type: ignore[attr-defined]
    return trial


def risky(p: float, *moved: str) -> tuple[float, tuple[str, ...]]:
    return (p, tuple(moved))


STILL = (0.0, ())
