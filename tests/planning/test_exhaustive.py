"""Exhaustive minimum over removal orders (fake oracles; the true-scene run is in the physics tests)."""
from __future__ import annotations

import pytest

from fake_oracles import SupportGraph, table_oracle
from planning.exhaustive import min_removals


def test_free_target():
    g = SupportGraph({"a": ["b"]}, ids=["a", "b", "t"])
    assert min_removals(g.ids, "t", g.safe) == ("t",)


def test_stack_comes_off_top_down():
    g = SupportGraph({"a": ["b"], "b": ["t"]}, ids=["t", "b", "a", "x", "y"])
    assert min_removals(g.ids, "t", g.safe) == ("a", "b", "t")


def test_minimum_counts_only_what_is_needed():
    # t carries a and b; c stands beside on the floor and is never removed
    g = SupportGraph({"a": ["t"], "b": ["t"], "d": ["c"]}, ids=["c", "d", "t", "a", "b"])
    seq = min_removals(g.ids, "t", g.safe)
    assert seq is not None and len(seq) == 3 and set(seq) == {"a", "b", "t"}


def test_none_when_no_collapse_free_order_exists():
    # a and t lean on each other: whichever goes first drops the other
    safe = lambda removed, box: False if {box, "a", "t"} == {"a", "t"} and not removed & {"a", "t"} else True
    assert min_removals(["t", "a", "c"], "t", safe) is None


def test_refuses_large_scenes():
    ids = [f"b{i}" for i in range(12)]
    with pytest.raises(ValueError, match="at most"):
        min_removals(ids, "b0", lambda r, b: True, max_boxes=10)


def test_asks_each_state_at_most_once():
    g = SupportGraph({"a": ["t"], "b": ["t"], "c": ["a", "b"]}, ids=["t", "a", "b", "c", "d"])
    oracle = table_oracle(lambda r, b: (g(r, b).collapse_prob, g(r, b).moved))
    seq = min_removals(g.ids, "t", lambda r, b: oracle(r, b).risk == 0.0)
    assert seq == ("c", "a", "b", "t")
    assert len(oracle.asked) == len(set(oracle.asked))
