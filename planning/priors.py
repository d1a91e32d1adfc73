"""What a robot cell knows about its stock and its gripper: the priors of its sample worlds.

A cell file's `[planning]` section (console/cell.py reads and checks it) gives the range of its
boxes' masses, the friction of its cardboard, how its gripper pulls, and the highest calibrated
chance of a collapse a plan may carry; the planning side takes them as this frozen dataclass and
never reads the file. The defaults are `Uncertainty()`'s and docs/physics.md says why.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

from shelfpick.planning.calibration import DEFAULT_MAX_PLAN_RISK
from shelfpick.planning.uncertainty import PULL_MODES, Uncertainty

_DEFAULT = Uncertainty()


@dataclass(frozen=True)
class CellPriors:
    """A cell's stock and gripper as the sample worlds draw them, and its plan threshold."""

    mass: tuple[float, float] = _DEFAULT.mass              # kg per box, drawn log-uniform
    friction: tuple[float, float] = _DEFAULT.friction      # one per world
    pull_modes: tuple[str, ...] = _DEFAULT.pull_modes      # "lift", "drag", "ride", one per world
    max_plan_risk: float = DEFAULT_MAX_PLAN_RISK           # safe: calibrated upper end below this

    def __post_init__(self) -> None:
        lo, hi = self.mass
        if not 0 < lo <= hi:
            raise ValueError(f"mass range must be 0 < low <= high, got {self.mass}")
        lo, hi = self.friction
        if not 0 < lo <= hi:
            raise ValueError(f"friction range must be 0 < low <= high, got {self.friction}")
        if not self.pull_modes or any(m not in PULL_MODES for m in self.pull_modes):
            raise ValueError(f"pull modes must be some of {', '.join(PULL_MODES)}, got {self.pull_modes}")
        if not 0 < self.max_plan_risk <= 1:
            raise ValueError(f"max_plan_risk must be in (0, 1], got {self.max_plan_risk}")

    def model(self, base: Uncertainty | None = None) -> Uncertainty:
        """`base` (default `Uncertainty()`) with this cell's masses, friction and pull modes."""
        return replace(base if base is not None else Uncertainty(), mass=tuple(self.mass),
                       friction=tuple(self.friction), pull_modes=tuple(self.pull_modes))
