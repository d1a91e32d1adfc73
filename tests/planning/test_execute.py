"""execute_plan on the true scene: the verdict the bench and `shelfpick simulate` rely on."""
from __future__ import annotations

import json

from shelfpick.planning.execute import execute_plan
from tests.planning.sim_scenes import grid, stacked


def test_target_under_a_box_collapses_but_removing_the_top_first_is_ok():
    bad = execute_plan(stacked(), ["a"])
    assert not bad.ok and bad.collapsed
    assert bad.steps[0].collapsed == ("b",) and bad.failed_step == 0
    good = execute_plan(stacked(), ["b", "a"])
    assert good.ok and not good.collapsed
    assert [s.box for s in good.steps] == ["b", "a"]
    assert all(s.extracted for s in good.steps)


def test_verdict_json_has_per_step_moves_and_flags():
    ex = execute_plan(stacked(), ["a", "b"], seed=3)
    doc = json.loads(json.dumps(ex.to_json()))
    assert doc["ok"] is False and doc["collapse"] is True and doc["failed_step"] == 0
    s0, s1 = doc["steps"]
    assert s0["box"] == "a" and s0["collapse"] is True and s0["collapsed"] == ["b"]
    assert s0["moved"]["b"] > 0.05
    assert s1["box"] == "b" and s1["extracted"] is False  # it already fell off the shelf
    assert doc["seed"] == 3


def test_same_seed_same_execution():
    a = execute_plan(grid(3, 3), ["b2", "b5", "b4"], seed=1)
    b = execute_plan(grid(3, 3), ["b2", "b5", "b4"], seed=1)
    assert a.to_json()["steps"] == b.to_json()["steps"]
    assert a.ok


def test_record_keeps_frames():
    ex = execute_plan(stacked(), ["c"], record=True)
    assert ex.steps[0].frames and "frames" in ex.to_json(frames=True)["steps"][0]
