"""Dropping the blockers an extraction plan does not need, against fake oracles."""
from __future__ import annotations

import pytest

from fake_oracles import STILL, SupportGraph, risky, table_oracle
from shelfpick.planning.extract import SearchResult, search_extract
from shelfpick.planning.shorten import shorten_extraction


def _wasted_blocker(removed, box):
    """t is pinned by b; a failed pull of t moves a first (a greedy search pulls it), but
    only b's removal frees t."""
    if box == "t" and "b" not in removed:
        return risky(1.0, "a", "b") if "a" not in removed else risky(1.0, "b")
    return STILL


def test_a_blocker_that_did_not_free_the_target_is_dropped():
    oracle = table_oracle(_wasted_blocker)
    greedy = search_extract(["a", "b", "t"], "t", oracle)
    assert greedy.sequence == ("a", "b", "t") and greedy.safe   # what Algorithm 1 does
    short = shorten_extraction(greedy, oracle)
    assert short.sequence == ("b", "t") and short.safe
    assert [p.box for p in short.predicted] == ["b", "t"]


def test_a_needed_blocker_stays():
    g = SupportGraph({"a": ["b"], "b": ["t"]}, ids=["t", "b", "a"])
    res = search_extract(g.ids, "t", g)
    assert res.sequence == ("a", "b", "t")
    assert shorten_extraction(res, g).sequence == ("a", "b", "t")


@pytest.mark.parametrize("alone, kept", [(0.25, ("t",)), (0.3, ("a", "t"))])
def test_an_unsafe_plan_is_shortened_only_when_no_likelier_to_collapse(alone, kept):
    # with a pulled first: 0.9 * 0.8 = 0.72 of no collapse; t alone: 1 - alone
    def rules(removed, box):
        if box == "t":
            return risky(0.2 if "a" in removed else alone, "a")
        return risky(0.1, "x")
    oracle = table_oracle(rules)
    plan = SearchResult(("a", "t"), (oracle(frozenset(), "a"), oracle(frozenset({"a"}), "t")), False)
    short = shorten_extraction(plan, oracle)
    assert short.sequence == kept and not short.safe
    assert [p.risk for p in short.predicted] == ([alone] if kept == ("t",) else [0.1, 0.2])


def test_the_screen_is_asked_with_the_most_a_step_may_risk():
    oracle = table_oracle(_wasted_blocker)
    asked = []

    def screen(removed, box, bound):
        asked.append((removed, box, bound))
        return oracle(removed, box)
    greedy = search_extract(["a", "b", "t"], "t", oracle)
    short = shorten_extraction(greedy, oracle, screen=screen)
    assert short.sequence == ("b", "t")
    assert (frozenset({"b"}), "t", 0.0) in asked


def test_an_unsafe_candidate_is_dropped_at_its_first_losing_step():
    # plan a, b, t with success 0.9 * 1 * 0.9 = 0.81; without a, b risks 0.5: lost at b, t never asked
    def rules(removed, box):
        if box == "b":
            return risky(0.0 if "a" in removed else 0.5, "x")
        if box == "t":
            return risky(0.1 if "b" in removed else 0.5, "b")
        return risky(0.1, "x")
    oracle = table_oracle(rules)
    plan = SearchResult(("a", "b", "t"), (oracle(frozenset(), "a"), oracle(frozenset({"a"}), "b"),
                                          oracle(frozenset({"a", "b"}), "t")), False)
    bounds = []

    def screen(removed, box, bound):
        bounds.append((box, removed, round(bound, 6)))
        return oracle(removed, box)
    short = shorten_extraction(plan, oracle, screen=screen)
    assert short.sequence == ("a", "b", "t")
    # dropping a: b may risk at most 1 - 0.81 = 0.19 (0.5 loses), so t without a is never asked
    assert ("b", frozenset(), 0.19) in bounds
    assert not [x for x in bounds if x[:2] == ("t", frozenset({"b"}))]


def test_a_passed_deadline_leaves_the_plan_alone():
    oracle = table_oracle(_wasted_blocker)
    greedy = search_extract(["a", "b", "t"], "t", oracle)
    assert shorten_extraction(greedy, oracle, passed=lambda: True) is greedy
