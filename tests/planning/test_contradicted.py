"""Faces perception doubts in planning: a plan touching one is not declared safe, and says why."""
from __future__ import annotations

import json
from dataclasses import replace

from shelfpick.perception.boxes import flag_contradicted, make_valid
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.contradicted import doubted, touches
from shelfpick.planning.plan import StepPrediction
from shelfpick.planning.planner import make_plan
from sim_scenes import stacked


def doubt(scene: Scene, *ids: str) -> Scene:
    """The scene with the named boxes marked as perception marks the faces of a contradiction."""
    return replace(scene, boxes=tuple(
        replace(b, extra={**b.extra, "perceived": {"contradicted": True}}) if b.id in ids else b for b in scene.boxes))


def test_perception_marks_every_box_a_contradiction_names_and_the_mark_survives_the_file(tmp_path):
    front = Box("b1", (0.3, 0.25, 0.3), (0.0, 0.125, 0.15), (1.0, 0.0, 0.0, 0.0), None, False, 1, {"perceived": {}})
    behind = Box("b10", (0.2, 0.25, 0.2), (0.19, 0.04 + 0.125, 0.1), (1.0, 0.0, 0.0, 0.0), None, False, 2,
                 {"perceived": {}})
    apart = Box("b11", (0.2, 0.25, 0.2), (-0.35, 0.125, 0.1), (1.0, 0.0, 0.0, 0.0), None, False, 3, {"perceived": {}})
    boxes, notes = make_valid([front, behind, apart], Shelf())
    marked = flag_contradicted(boxes, notes)
    scene = Scene(Shelf(), tuple(marked))
    assert doubted(scene) == ["b1", "b10"]          # "b1" is not read inside "b10" or "b11"
    path = tmp_path / "scene.json"
    scene.save(path)
    assert doubted(Scene.load(path)) == ["b1", "b10"]
    assert json.loads(path.read_text())["boxes"][1]["perceived"]["contradicted"] is True


def test_a_step_on_against_or_moving_a_doubted_box_is_named():
    scene = doubt(stacked(), "a")        # b stands on a; c stands alone, 20 cm from a
    assert touches(scene, ["b"]) == ["step 1: pulling b touches a, a box whose perceived face cannot be right as seen"]
    assert touches(scene, ["a"]) == ["step 1: pulling a is a box whose perceived face cannot be right as seen"]
    assert touches(scene, ["c"]) == []
    assert touches(scene, ["c"], [StepPrediction("c", 0.1, 0.0, ("c", "b"))]) == [
        "step 1: b, moved by pulling c, touches a, a box whose perceived face cannot be right as seen"]
    assert touches(stacked(), ["b"]) == []


def test_a_plan_that_touches_a_doubted_face_is_not_safe_and_one_that_does_not_is_as_before():
    plain = make_plan(stacked(), "extract", "b", samples=2, verify=0)
    told = make_plan(doubt(stacked(), "a"), "extract", "b", samples=2, verify=0)
    assert "contradicted" not in plain.extra
    assert told.sequence == plain.sequence and told.predicted == plain.predicted and not told.safe
    assert told.extra["contradicted"] == {
        "boxes": ["a"], "touched": ["step 1: pulling b touches a, a box whose perceived face cannot be right as seen"]}
    # with an oracle that calls every pull harmless, the mark alone makes the difference
    from fake_oracles import SupportGraph

    class Calm:
        """A predictor whose every pull moves nothing."""

        trial = SupportGraph({}, ids=("a", "b", "c"))

        def close(self):
            pass

    assert make_plan(stacked(), "extract", "b", predictor=Calm()).safe
    assert not make_plan(doubt(stacked(), "a"), "extract", "b", predictor=Calm()).safe
    far = make_plan(doubt(stacked(), "a"), "extract", "c", predictor=Calm())
    assert far.safe and far.extra["contradicted"] == {"boxes": ["a"], "touched": []}


def test_shelfpick_plan_warns_what_touches_a_doubted_face(tmp_path, capsys):
    from shelfpick.console.cli import main

    path = tmp_path / "scene.json"
    doubt(stacked(), "a").save(path)
    out = tmp_path / "plan.json"
    assert main(["plan", str(path), "--task", "extract", "--target", "b", "--samples", "2", "--workers", "1",
                 "--out", str(out)]) == 0
    assert ("step 1: pulling b touches a, a box whose perceived face cannot be right as seen (perception said "
            "its faces cannot all be right); the plan is not safe") in capsys.readouterr().err
    plan = json.loads(out.read_text())
    assert plan["safe"] is False and plan["contradicted"]["boxes"] == ["a"]
