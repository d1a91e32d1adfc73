"""Plan documents: round trip, content hash, and the errors users see."""
from __future__ import annotations

import pytest

from shelfpick.perception.errors import FormatError
from shelfpick.planning.plan import Plan, StepPrediction


def test_round_trip_and_hash(tmp_path):
    plan = Plan("extract", "b3", "physics", ("b5", "b3"),
                (StepPrediction("b5", 0.0, 0.0, ()), StepPrediction("b3", 0.1, 0.0, ("b4",))),
                safe=False, timing={"planning_s": 0.2}, seed=7)
    path = tmp_path / "p.json"
    plan.save(path)
    again = Plan.load(path)
    assert again == plan
    assert again.risk == pytest.approx(0.1)
    assert again.content_hash() == plan.content_hash()
    other = Plan("extract", "b3", "physics", ("b3",))
    assert other.content_hash() != plan.content_hash()
    # the hash identifies what the robot does, not the planner's commentary
    assert Plan("extract", "b3", "heuristic", ("b5", "b3")).content_hash() == plan.content_hash()


@pytest.mark.parametrize("doc, field", [
    ({"task": "dance"}, "task"),
    ({"sequence": ["b1", "b1", "b3"]}, "sequence"),
    ({"sequence": ["b3", "b1"]}, "sequence"),
    ({"target": None}, "target"),
    ({"format": "x"}, "format"),
    ({"predicted": [{"box": "b3", "collapse_prob": 2}]}, "predicted[0].collapse_prob"),
])
def test_bad_plans_are_named(doc, field):
    base = {"format": "shelfpick.plan/1", "task": "extract", "target": "b3", "planner": "physics",
            "sequence": ["b5", "b3"]}
    base.update(doc)
    with pytest.raises(FormatError) as err:
        Plan.from_json(base, "plan.json")
    assert f"plan.json: {field}" in str(err.value)


def test_check_against_names_unknown_ids():
    plan = Plan("clear", None, "heuristic", ("b1", "b9"))
    with pytest.raises(FormatError, match=r"sequence\[1\]: unknown box id 'b9'"):
        plan.check_against(("b1", "b2"), "plan.json")


@pytest.mark.parametrize("field, value", [("seed", "zero"), ("seed", 1.5), ("seed", True),
                                          ("timing", {"planning_s": "fast"}), ("timing", {"x": None})])
def test_a_plan_with_a_bad_seed_or_timing_names_the_field(field, value):
    doc = {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "physics",
           "sequence": ["a"], field: value}
    with pytest.raises(FormatError) as exc:
        Plan.from_json(doc, "p.json")
    assert exc.value.field.startswith(field)
