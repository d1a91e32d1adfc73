"""What the planners may ask of a predictor: the protocols `make_plan` relies on.

A planner is a pure function over an oracle, ``trial(removed, box) -> StepPrediction``.
A sampling predictor (`planning.predict.Predictor`) can do more, and `make_plan`
uses it when it is there: screen a candidate only until it can no longer be safe,
find the least risky box lazily, report its statistics and whether the observed
shelf stands as seen. Test doubles implement `Predicting` only.
"""
from __future__ import annotations

from typing import Any, Protocol, Sequence, runtime_checkable

from shelfpick.planning.plan import StepPrediction


@runtime_checkable
class Predicting(Protocol):
    """Predicts one removal; closed by whoever made it."""

    def trial(self, removed: frozenset[str], box: str) -> StepPrediction: ...

    def close(self) -> None: ...


@runtime_checkable
class Screening(Predicting, Protocol):
    """A predictor over samples that can stop sampling early (docs/speed.md)."""

    stats: dict[str, Any]        # "pulls": physics pulls run so far, ...
    scene_check: dict[str, Any]  # planning.sample_worlds.scene_check of its worlds

    @property
    def worlds(self) -> int: ...  # the sample worlds behind every risk it gives

    def screen(self, removed: frozenset[str], box: str, risk: float = 0.0) -> StepPrediction: ...

    def least_risky(self, removed: frozenset[str], boxes: Sequence[str]) -> str: ...


@runtime_checkable
class Verifying(Predicting, Protocol):
    """A predictor that can ask a plan of more sample worlds than the search used."""

    verified_worlds: int         # the worlds behind the last `verify`

    def verify(self, sequence: Sequence[str], extra: int) -> tuple[StepPrediction, ...]: ...
