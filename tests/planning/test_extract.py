"""Algorithm 1 (physics extract) against fake oracles: no physics needed."""
from __future__ import annotations

import random
import time

import pytest

from fake_oracles import STILL, SupportGraph, risky, table_oracle
from shelfpick.planning.exhaustive import min_removals
from shelfpick.planning.extract import CountingOracle, search_extract


def test_free_target_is_pulled_alone_with_one_trial():
    g = SupportGraph({"a": ["b"]}, ids=["a", "b", "t"])
    res = search_extract(g.ids, "t", g)
    assert res.sequence == ("t",)
    assert res.safe and res.risk == 0.0
    assert res.calls == 1 and len(g.asked) == 1


def test_stack_on_target_is_removed_top_down():
    # a rests on b, b rests on t: pulling t first would drop both
    g = SupportGraph({"a": ["b"], "b": ["t"]}, ids=["t", "b", "a", "x"])
    res = search_extract(g.ids, "t", g)
    assert res.sequence == ("a", "b", "t")
    assert res.safe
    assert [p.box for p in res.predicted] == list(res.sequence)
    assert all(p.risk == 0.0 for p in res.predicted)
    # t, b, a, then b and t again: nothing is asked twice
    assert res.calls == len(set(g.asked)) == len(g.asked) == 5


def test_two_boxes_on_target_both_come_off_first():
    g = SupportGraph({"a": ["t"], "b": ["t"]}, ids=["t", "a", "b"])
    res = search_extract(g.ids, "t", g)
    assert set(res.sequence[:-1]) == {"a", "b"} and res.sequence[-1] == "t"
    assert res.safe


def test_two_cycle_terminates_unsafe_and_names_its_risk():
    # an impossible oracle: pulling t moves x, pulling x moves t
    oracle = table_oracle(lambda removed, box: risky(1.0, "x") if box == "t" else risky(1.0, "t"))
    res = search_extract(["t", "x"], "t", oracle)
    assert res.sequence[-1] == "t"
    assert len(set(res.sequence)) == len(res.sequence)
    assert not res.safe and res.risk == 1.0


def test_three_cycle_is_not_recursed_into_again():
    # t -> a -> b -> t: every pull moves the next box of the cycle
    nxt = {"t": "a", "a": "b", "b": "t"}
    oracle = table_oracle(lambda removed, box: risky(0.5, nxt[box]) if nxt[box] not in removed else STILL)
    res = search_extract(["t", "a", "b"], "t", oracle)
    assert res.sequence[-1] == "t"
    assert len(set(res.sequence)) == len(res.sequence)
    assert not res.safe and res.risk == 0.5
    assert res.calls <= 6


def test_other_moved_boxes_are_tried_when_the_first_cannot_come_out():
    # pulling t moves a and b while b is there; a cannot come out (it would drop t);
    # b comes out freely and then t is free. The plain method would be stuck on a.
    def rules(removed, box):
        if box == "t":
            return STILL if "b" in removed else risky(1.0, "a", "b")
        if box == "a":
            return risky(1.0, "t")
        return STILL
    oracle = table_oracle(rules)
    res = search_extract(["t", "a", "b"], "t", oracle)
    assert res.sequence == ("b", "t")
    assert res.safe


def test_risk_threshold_accepts_a_small_collapse_probability():
    g = SupportGraph({"a": ["t"]}, ids=["t", "a"], prob=0.2)
    assert search_extract(g.ids, "t", g, risk=0.3).sequence == ("t",)
    assert search_extract(g.ids, "t", g, risk=0.0).sequence == ("a", "t")


def test_no_safe_plan_returns_the_least_risky_one():
    # t is very risky (0.9) while a is there; a's own pull risks 0.2 (it nudges t)
    def rules(removed, box):
        if box == "t":
            return STILL if "a" in removed else risky(0.9, "a")
        return risky(0.2, "t")
    res = search_extract(["t", "a"], "t", table_oracle(rules))
    assert res.sequence == ("a", "t")
    assert not res.safe
    assert res.risk == pytest.approx(0.2)


def test_pulling_now_wins_when_the_blockers_risk_more():
    def rules(removed, box):
        if box == "t":
            return STILL if "a" in removed else risky(0.3, "a")
        return risky(0.8, "t")
    res = search_extract(["t", "a"], "t", table_oracle(rules))
    assert res.sequence == ("t",)
    assert not res.safe and res.risk == pytest.approx(0.3)


def test_depth_bound_stops_the_recursion():
    chain = {f"c{i}": [f"c{i - 1}"] for i in range(1, 6)}  # c5 on c4 ... on c0
    g = SupportGraph(chain)
    full = search_extract(g.ids, "c0", g)
    assert full.sequence == ("c5", "c4", "c3", "c2", "c1", "c0") and full.safe
    # an oracle that only ever names the box directly on top needs depth 5
    def rules(removed, box):
        i = int(box[1:])
        above = f"c{i + 1}"
        return risky(1.0, above) if i < 5 and above not in removed else STILL
    deep = search_extract(g.ids, "c0", table_oracle(rules))
    assert deep.sequence == full.sequence and deep.safe
    shallow = search_extract(g.ids, "c0", table_oracle(rules), max_depth=2)
    assert shallow.sequence[-1] == "c0" and not shallow.safe
    assert len(shallow.sequence) <= 3


def test_other_moved_boxes_shortcut_the_depth_bound():
    # with every box above named as moved, the top one is reachable at depth 1
    chain = {f"c{i}": [f"c{i - 1}"] for i in range(1, 6)}
    res = search_extract(SupportGraph(chain).ids, "c0", SupportGraph(chain), max_depth=1)
    assert res.sequence == ("c5", "c4", "c3", "c2", "c1", "c0") and res.safe


def test_deadline_in_the_past_still_returns_a_plan_and_says_so():
    g = SupportGraph({"a": ["b"], "b": ["t"]})
    res = search_extract(g.ids, "t", g, deadline=time.monotonic() - 1)
    assert res.timed_out
    assert res.sequence[-1] == "t" and not res.safe


def test_unknown_target_is_refused():
    with pytest.raises(ValueError, match="'zz'"):
        search_extract(["a"], "zz", table_oracle(lambda r, b: STILL))


def test_counting_oracle_memoises():
    oracle = table_oracle(lambda r, b: STILL)
    c = CountingOracle(oracle)
    c(frozenset(), "a")
    c(frozenset(), "a")
    c(frozenset({"b"}), "a")
    assert c.calls == 2 and len(oracle.asked) == 2


def _random_dag(rng: random.Random, n: int) -> SupportGraph:
    ids = [f"b{i}" for i in range(n)]
    rests = {}
    for i in range(1, n):
        k = rng.choice([0, 1, 1, 2])
        rests[ids[i]] = rng.sample(ids[:i], min(k, i))
    return SupportGraph(rests, ids=ids)


@pytest.mark.parametrize("seed", range(15))
def test_on_stacking_graphs_the_search_finds_the_minimum(seed):
    """On a support DAG a safe plan always exists; Algorithm 1 must hit the exhaustive minimum."""
    rng = random.Random(seed)
    g = _random_dag(rng, rng.randint(3, 8))
    for target in g.ids:
        res = search_extract(g.ids, target, g)
        best = min_removals(g.ids, target, g.safe)
        assert res.safe and best is not None
        assert len(res.sequence) == len(best)
        assert set(res.sequence) == set(best)


def test_fallback_ranks_plans_by_the_chance_that_nothing_collapses():
    # pulling t now risks 0.5; taking a first risks 0.4 and leaves t at 0.4 (b leans on it):
    # 0.6 * 0.6 = 0.36 < 0.5, so pulling t now is the better bet although its step risk is higher
    def rules(removed, box):
        if box == "t":
            return risky(0.4, "b") if "a" in removed else risky(0.5, "a")
        if box == "a":
            return risky(0.4, "t")
        return risky(1.0, "t")  # b cannot come out either
    res = search_extract(["t", "a", "b"], "t", table_oracle(rules))
    assert res.sequence == ("t",)
    assert res.success_prob == pytest.approx(0.5)


def test_fallback_takes_the_blocker_when_that_is_the_better_bet():
    def rules(removed, box):
        if box == "t":
            return risky(0.1, "b") if "a" in removed else risky(0.6, "a")
        if box == "a":
            return risky(0.2, "t")
        return risky(1.0, "t")
    res = search_extract(["t", "a", "b"], "t", table_oracle(rules))
    assert res.sequence == ("a", "t")  # 0.8 * 0.9 = 0.72 > 0.4
    assert res.success_prob == pytest.approx(0.72) and res.risk == pytest.approx(0.2)
