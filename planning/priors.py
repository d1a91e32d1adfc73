"""What a robot cell knows about its stock and its gripper: the priors of its sample worlds.

A cell file's `[planning]` section gives the range of its boxes' masses, the friction of its
cardboard, how its gripper pulls, and the highest calibrated chance of a collapse a plan may
carry. The section is checked here (`CellPriors.from_section`), once for both readers of a cell
file: the console (console/cell.py) and `shelfpick plan --cell` (planning/cmd_plan.py), which both
read the file with planning.cell_file. The defaults are `Uncertainty()`'s and docs/physics.md says why.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any, Mapping

from shelfpick.perception.errors import FormatError
from shelfpick.planning.calibration import DEFAULT_MAX_PLAN_RISK
from shelfpick.planning.uncertainty import PULL_MODES, Uncertainty

_DEFAULT = Uncertainty()
PLANNING_KEYS = ("mass_kg", "friction", "pull_modes", "max_plan_risk")   # a cell file's [planning] keys
# the bounds of the cell file's values (docs/cli.md "Bounds")
RANGES = {"mass_kg": ("mass", 0.01, 1000.0), "friction": ("friction", 0.01, 2.0)}
MAX_PLAN_RISK = (1e-4, 1.0)


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

    @classmethod
    def from_section(cls, section: Mapping[str, Any], origin: str) -> "CellPriors":
        """The priors a cell file's `[planning]` table gives (defaults for the keys it leaves out);
        a FormatError naming `origin`, `planning.<key>` and the value on the first wrong one."""
        return cls(**section_kwargs(section, origin))

    def model(self, base: Uncertainty | None = None) -> Uncertainty:
        """`base` (default `Uncertainty()`) with this cell's masses, friction and pull modes."""
        return replace(base if base is not None else Uncertainty(), mass=tuple(self.mass),
                       friction=tuple(self.friction), pull_modes=tuple(self.pull_modes))


def section_kwargs(section: Mapping[str, Any], origin: str) -> dict[str, Any]:
    """A `[planning]` table checked, as CellPriors' keyword arguments (only the keys it gives)."""
    if not isinstance(section, Mapping):
        raise FormatError(origin, "planning", f"expected a table [planning], got {section!r}")
    unknown = sorted(set(section) - set(PLANNING_KEYS))
    if unknown:
        raise FormatError(origin, f"planning.{unknown[0]}", f"unknown key (known: {', '.join(PLANNING_KEYS)})")
    out: dict[str, Any] = {}
    for key, (name, lo, hi) in RANGES.items():
        if key in section:
            out[name] = _range(section[key], key, lo, hi, origin)
    if "pull_modes" in section:
        v = section["pull_modes"]
        if (not isinstance(v, list) or not v or any(not isinstance(m, str) or m not in PULL_MODES for m in v)
                or len(set(v)) != len(v)):
            raise FormatError(origin, "planning.pull_modes", f"expected a list of distinct modes of "
                                                             f"{', '.join(PULL_MODES)}, got {v!r}")
        out["pull_modes"] = tuple(v)
    if "max_plan_risk" in section:
        v = section["max_plan_risk"]
        lo, hi = MAX_PLAN_RISK
        if not _number(v) or not lo <= v <= hi:
            raise FormatError(origin, "planning.max_plan_risk", f"expected a number in [{lo:g}, {hi:g}], got {v!r}")
        out["max_plan_risk"] = float(v)
    return out


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _range(v: Any, key: str, lo: float, hi: float, origin: str) -> tuple[float, float]:
    """[low, high] with lo <= low <= high <= hi, else a FormatError naming `planning.<key>`."""
    if not (isinstance(v, list) and len(v) == 2 and all(_number(x) and lo <= x <= hi for x in v) and v[0] <= v[1]):
        raise FormatError(origin, f"planning.{key}", f"expected [low, high] with {lo:g} <= low <= high <= {hi:g}, "
                                                     f"got {v!r}")
    return float(v[0]), float(v[1])
