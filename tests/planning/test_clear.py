"""Algorithm 2 (physics clear) against fake oracles, and its visiting order."""
from __future__ import annotations

import time

import pytest

from fake_oracles import STILL, SupportGraph, risky, table_oracle
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.clear import prefer_baseline, search_clear, visit_order
from shelfpick.planning.extract import SearchResult
from shelfpick.planning.plan import StepPrediction


def test_skipped_boxes_are_revisited_until_the_shelf_is_empty():
    # a on b on c, visited bottom first (the worst order)
    g = SupportGraph({"a": ["b"], "b": ["c"]}, ids=["c", "b", "a"])
    res = search_clear(["c", "b", "a"], g)
    assert res.sequence == ("a", "b", "c")
    assert res.safe and res.risk == 0.0
    assert [p.box for p in res.predicted] == ["a", "b", "c"]
    # pass 1: c, b, a; pass 2: c, b; pass 3: c
    assert res.calls == 6


def test_safe_boxes_come_out_in_visiting_order():
    g = SupportGraph({}, ids=["x", "y", "z"])
    res = search_clear(["z", "x", "y"], g)
    assert res.sequence == ("z", "x", "y") and res.calls == 3


def test_terminates_when_everything_is_unsafe():
    oracle = table_oracle(lambda removed, box: risky(1.0, "someone"))
    ids = [f"b{i}" for i in range(7)]
    res = search_clear(ids, oracle)
    assert sorted(res.sequence) == sorted(ids)
    assert not res.safe and res.risk == 1.0
    assert res.calls <= len(ids) * (len(ids) + 1) // 2


def test_forced_steps_take_the_least_risky_box():
    risks = {"a": 0.5, "b": 0.2, "c": 0.9}
    res = search_clear(["a", "b", "c"], table_oracle(lambda r, box: risky(risks[box], "x")))
    assert res.sequence == ("b", "a", "c")
    assert not res.safe and res.risk == pytest.approx(0.9)


def test_one_forced_step_then_safe_again():
    # a and b lean on each other: whichever goes first drops the other; then all is free
    def rules(removed, box):
        other = {"a": "b", "b": "a"}.get(box)
        if other and other not in removed:
            return risky(0.4 if box == "b" else 0.6, other)
        return STILL
    res = search_clear(["a", "b", "c"], table_oracle(rules))
    assert res.sequence == ("c", "b", "a")
    assert not res.safe and res.risk == pytest.approx(0.4)


def test_risk_threshold():
    g = SupportGraph({"a": ["b"]}, ids=["b", "a"], prob=0.1)
    assert search_clear(["b", "a"], g, risk=0.1).sequence == ("b", "a")
    assert search_clear(["b", "a"], g, risk=0.0).sequence == ("a", "b")


def test_deadline_pulls_the_rest_in_order():
    g = SupportGraph({"a": ["b"], "b": ["c"]}, ids=["c", "b", "a"])
    res = search_clear(["c", "b", "a"], g, deadline=time.monotonic() - 1)
    assert res.sequence == ("c", "b", "a") and res.timed_out and not res.safe


def _box(bid, x, z, h, y=0.15, d=0.2):
    return Box(bid, (0.2, d, h), (x, y, z), (1.0, 0.0, 0.0, 0.0))


def test_visit_order_is_top_down_then_front_first():
    scene = Scene(Shelf(), (
        _box("low", -0.3, 0.1, 0.2),
        _box("top", -0.3, 0.3, 0.2),
        _box("back", 0.2, 0.15, 0.3, y=0.2, d=0.1),     # top at 0.3, front at y=0.15
        _box("front", 0.0, 0.15, 0.3, y=0.1, d=0.1),    # top at 0.3, front at y=0.05
        _box("floor", 0.35, 0.05, 0.1),
    ))
    assert visit_order(scene) == ("top", "front", "back", "low", "floor")


def test_a_forced_pull_goes_to_a_higher_box_the_samples_cannot_tell_apart():
    from shelfpick.planning.clear import sampling_error
    assert abs(sampling_error(0.1, 10) - 0.19) < 0.01 and sampling_error(1.0, 10) == 0.0

    def oracle(risks):
        return lambda removed, box: StepPrediction(box, risks(removed)[box], 0.0, ())
    # nothing is safe: 'hi' (0.25) is within 2 standard errors of 'lo' (0.1) at 10 worlds, not at 100
    first = {"hi": 0.25, "lo": 0.1}
    trial = oracle(lambda removed: {b: (0.0 if removed else r) for b, r in first.items()})
    assert search_clear(["hi", "lo"], trial, samples=10).sequence[0] == "hi"
    assert search_clear(["hi", "lo"], trial, samples=100).sequence[0] == "lo"
    assert search_clear(["hi", "lo"], trial).sequence[0] == "lo"           # no samples: least risky
    far = {"hi": 0.6, "lo": 0.1}
    trial = oracle(lambda removed: {b: (0.0 if removed else r) for b, r in far.items()})
    assert search_clear(["hi", "lo"], trial, samples=10).sequence[0] == "lo"


def test_after_each_pull_the_visit_starts_again_from_the_top():
    # 'a' is unsafe until 'b' is out; once 'b' is out, 'a' comes before 'c'
    def trial(removed, box):
        return StepPrediction(box, 1.0 if box == "a" and "b" not in removed else 0.0, 0.0, ())
    assert search_clear(["a", "b", "c"], trial).sequence == ("b", "a", "c")


def test_an_unsafe_plan_gives_way_to_the_baseline_order_when_that_is_predicted_likelier_to_hold():
    # the search's order pulls b (low) first: risk 0.3; the baseline's top-down a, b: 0.1 then 0
    def rules(removed, box):
        if box == "b":
            return (0.0, ()) if "a" in removed else (0.3, ("a",))
        return (0.1, ("x",))
    oracle = table_oracle(rules)
    plan = SearchResult(("b", "a"), (oracle(frozenset(), "b"), oracle(frozenset({"b"}), "a")), False)
    better = prefer_baseline(plan, ["a", "b"], oracle)
    assert better.sequence == ("a", "b") and better.success_prob == pytest.approx(0.9)
    # a baseline no likelier to hold, or a safe plan, leaves the plan alone
    worse = SearchResult(("a", "b"), (oracle(frozenset(), "a"), oracle(frozenset({"a"}), "b")), False)
    assert prefer_baseline(worse, ["b", "a"], oracle) is worse
    safe = SearchResult(("b", "a"), (StepPrediction("b", 0.0), StepPrediction("a", 0.0)), True)
    assert prefer_baseline(safe, ["a", "b"], oracle) is safe


def _two_orders(search_first: float, baseline_first: float):
    """An oracle where pulling `b` first risks `search_first` and `a` first `baseline_first`,
    the second pull of either order holding; and the search's plan (b, a)."""
    def rules(removed, box):
        if removed:
            return (0.0, ())
        return (search_first, ("a",)) if box == "b" else (baseline_first, ("b",))
    oracle = table_oracle(rules)
    plan = SearchResult(("b", "a"), (oracle(frozenset(), "b"), oracle(frozenset({"b"}), "a")), False)
    return oracle, plan


def test_within_the_worlds_resolution_the_baseline_order_wins():
    # search order 0.8 to hold, baseline 0.7: ten worlds' standard error at 0.8 is 0.126
    oracle, plan = _two_orders(0.2, 0.3)
    assert prefer_baseline(plan, ["a", "b"], oracle, worlds=10).sequence == ("a", "b")
    # without a world count the old rule holds: only a baseline predicted better replaces the plan
    assert prefer_baseline(plan, ["a", "b"], oracle) is plan


def test_a_baseline_order_clearly_worse_than_the_worlds_can_resolve_is_not_taken():
    # search order 0.8, baseline 0.5: worse by 0.3, more than two standard errors
    oracle, plan = _two_orders(0.2, 0.5)
    assert prefer_baseline(plan, ["a", "b"], oracle, worlds=10) is plan
    # and with a hundred worlds (resolution 0.04) even 0.7 against 0.8 is told apart
    oracle, plan = _two_orders(0.2, 0.3)
    assert prefer_baseline(plan, ["a", "b"], oracle, worlds=100) is plan
