"""What ten sample worlds can tell apart, and the order a person would use where they cannot.

A plan's chance that no step collapses is counted over N sample worlds, so it is known to
within about one standard error, sqrt(p(1 - p) / N): 0.14 at p = 0.7 with ten worlds. Where
two orders of the same boxes differ by less than that, the worlds have not decided between
them; the passes that offer the order a person would use (blockers top first, highest first
for a clearance) take it there, since the search's own order may pull a box from under a load.
Used by `reorder.reorder_extraction` and `clear.prefer_baseline`.
"""
from __future__ import annotations

import math

from shelfpick.planning.extract import SearchResult


def resolution(success: float, worlds: int | None) -> float:
    """One standard error of a chance of success counted over `worlds` sample worlds (0 without
    any): two plans whose chances differ by less are not told apart by those worlds."""
    if not worlds or worlds < 2:
        return 0.0
    return math.sqrt(success * (1.0 - success) / worlds)


def prefer(new: SearchResult | None, result: SearchResult, slack: float) -> SearchResult:
    """`new` (an order a person would use) unless the worlds predict it worse than `result` by more
    than `slack`; with no slack, only when they predict it better (a tie keeps `result`)."""
    if new is None or new.success_prob < result.success_prob - slack - 1e-9:
        return result
    if slack == 0.0 and new.success_prob <= result.success_prob + 1e-9:
        return result
    return new
