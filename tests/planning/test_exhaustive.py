"""Exhaustive minimum over removal orders (fake oracles; the true-scene run is in the physics tests)."""
from __future__ import annotations

import pytest

from fake_oracles import SupportGraph, table_oracle
from shelfpick.planning.exhaustive import min_removals


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


def _stack_scene():
    from shelfpick.perception.scene import Box, Scene, Shelf

    def box(bid, x, z):
        return Box(bid, (0.2, 0.2, 0.2), (x, 0.15, z), (1.0, 0.0, 0.0, 0.0))
    # "top" rests on "bot"; "free" stands alone
    return Scene(Shelf(), (box("bot", -0.3, 0.1), box("top", -0.3, 0.3), box("free", 0.3, 0.1)))


def test_true_scene_minimum_with_real_physics():
    from shelfpick.planning.exhaustive import exhaustive_minimum
    scene = _stack_scene()
    assert exhaustive_minimum(scene, "bot") == ("top", "bot")
    assert exhaustive_minimum(scene, "free") == ("free",)
    assert exhaustive_minimum(scene, "top") == ("top",)


def test_true_scene_oracle_replays_real_pulls():
    from shelfpick.planning.exhaustive import true_scene_oracle
    safe = true_scene_oracle(_stack_scene())
    try:
        assert not safe(frozenset(), "bot")          # pulling the bottom drops the top
        assert safe(frozenset(), "top")
        assert safe(frozenset({"top"}), "bot")       # restored from the snapshot after "top"
        with pytest.raises(KeyError):
            safe(frozenset({"free"}), "bot")         # a state nobody reached
        assert safe.calls() == 3
    finally:
        safe.close()
