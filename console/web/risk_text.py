"""A plan's risk in the words the supervisor reads, on the page and in the exported session."""
from __future__ import annotations

from typing import Any

from shelfpick.planning.plan import Plan


def pct(p: float) -> str:
    return f"{100.0 * p:.0f}%"


def plan_risk(plan: Plan) -> tuple[dict[str, Any], float, float, float] | None:
    """The gate's record of the plan (`search.plan_risk`) with its calibrated chance, the upper end
    of its interval and the cell's threshold as numbers; None for a plan without a readable one."""
    search = plan.extra.get("search", {}) if isinstance(plan.extra, dict) else {}
    g = search.get("plan_risk") if isinstance(search, dict) else None
    if not isinstance(g, dict):
        return None
    try:
        return (g, *(float(g[k]) for k in ("probability", "high", "max_plan_risk")))
    except (KeyError, TypeError, ValueError):
        return None


def risk_words(plan: Plan) -> str:
    """The plan's risk as a supervisor reads it: the gate's calibrated chance of a collapse (what
    "safe" is decided on) and, apart, the worst step's share of sample worlds in which it collapsed
    or collided (collisions do not enter the chance: a plan can be safe with a step that knocks
    a neighbour in half the worlds, and then this says so)."""
    risk = plan_risk(plan)
    worst = f"worst step collapses or collides in {pct(plan.risk)} of sample worlds"
    if risk is None:
        return worst
    _, p, hi, _ = risk
    return f"chance of a collapse {100 * p:.1f}%, up to {100 * hi:.1f}%; {worst}"
