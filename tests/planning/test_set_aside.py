"""Perceived faces no world can hold are set aside as unexplained matter, not the shelf refused."""
from __future__ import annotations

import json
import pickle
from dataclasses import replace

import pytest

from shelfpick.perception.errors import SceneError
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.overlap_repair import OverlapError
from shelfpick.planning.planner import make_plan
from shelfpick.planning.set_aside import MAX_SET_ASIDE, face_region, set_aside

I = (1.0, 0.0, 0.0, 0.0)


def seen(bid: str, size, centre) -> Box:
    """A perceived box: its front face as seen, its depth a placeholder."""
    return Box(bid, size, centre, I, None, False, None, {"perceived": {"distance": 1.0}})


def test_a_plan_away_from_two_faces_no_world_can_hold_is_made_and_says_what_was_set_aside(contradictory):
    with pytest.warns(UserWarning, match="set aside f and k as unexplained matter"):
        plan = make_plan(contradictory, "extract", "c", samples=2, verify=0)
    assert plan.sequence == ("c",)
    assert [a["boxes"] for a in plan.extra["set_aside"]] == [["f", "k"]]
    assert plan.extra["set_aside"][0]["why"].startswith("box 'f' and box 'k' overlap by 0.2")
    assert plan.extra["unexplained"]["touched"] == []


def test_the_plan_carries_the_hash_of_the_scene_it_was_given(contradictory):
    given = contradictory
    plan = make_plan(given, "extract", "c", samples=2, verify=0)
    other = make_plan(given.without(["f", "k"]), "extract", "c", samples=2, verify=0)
    assert plan.provenance["scene_hash"] != other.provenance["scene_hash"]


def test_a_plan_that_comes_near_a_set_aside_face_is_not_safe(contradictory):
    plan = make_plan(contradictory, "extract", "n", samples=2, verify=0)
    assert "n" in plan.sequence and not plan.safe
    assert any("pulling n touches unexplained matter aside-f" in t for t in plan.extra["unexplained"]["touched"])


def test_a_target_among_the_faces_or_a_scene_with_depths_is_still_refused(contradictory):
    with pytest.raises(SceneError, match="box 'f' and box 'k' overlap by"):
        make_plan(contradictory, "extract", "f", samples=2, verify=0)
    known = contradictory.with_boxes(replace(b, depth_known=True) for b in contradictory.boxes)
    with pytest.raises(SceneError, match="overlap"):
        make_plan(known, "extract", "c", samples=2, verify=0)


def test_a_shelf_that_needs_more_set_aside_than_the_limit_is_refused():
    pairs = []
    for i in range(MAX_SET_ASIDE // 2 + 1):      # one pair more than may be set aside, side by side
        x = -0.38 + 0.25 * i
        pairs += [seen(f"f{i}", (0.2, 0.25, 0.2), (x, 0.125, 0.1)), seen(f"k{i}", (0.2, 0.25, 0.2), (x, 0.165, 0.1))]
    with pytest.raises(SceneError, match="overlap by"):
        make_plan(Scene(Shelf(), tuple(pairs)), "clear", samples=2, verify=0)


def test_a_set_aside_face_is_matter_from_its_seen_face_back_and_the_error_keeps_its_boxes(contradictory):
    scene = set_aside(contradictory, ("f", "k"), "why")
    assert scene.ids == ("n", "c") and [u.id for u in scene.unexplained] == ["aside-f", "aside-k"]
    u = face_region(contradictory.box("f"), None, "why")
    assert u.columns == ((pytest.approx(0.05), pytest.approx(0.35), pytest.approx(0.0), pytest.approx(0.3),
                          pytest.approx(0.0)),)
    assert u.pixels == 1 and u.area_m2 == pytest.approx(0.09)
    back = Scene.from_json(json.loads(json.dumps(scene.to_json())))   # a scene with it is still a scene file
    assert back.ids == scene.ids and back.unexplained == scene.unexplained
    err = pickle.loads(pickle.dumps(OverlapError("msg", ("a", "b"), "inner")))
    assert isinstance(err, SceneError) and (str(err), err.boxes, err.detail) == ("msg", ("a", "b"), "inner")


def test_a_plans_record_rebuilds_the_scene_it_was_made_on(contradictory):
    """A view or a replay has only the plan: its `extra["set_aside"]` rebuilt on the given scene is
    the scene `build_setting_aside` planned on; a record repeated (two planners) or naming a box
    the scene lacks adds nothing."""
    from shelfpick.planning.predict import Predictor
    from shelfpick.planning.set_aside import SetAside, build_setting_aside

    with pytest.warns(UserWarning):
        predictor, built = build_setting_aside(contradictory, "c", lambda sc: Predictor(sc, samples=2))
    predictor.close()
    assert built.boxes() == {"f", "k"}
    record = list(built.entries) * 2 + [{"boxes": ["gone"], "why": "x"}]
    again = SetAside.from_entries(contradictory, record)
    assert again.planned == built.planned and again.entries == built.entries and again.boxes() == {"f", "k"}
    assert [u.id for u in again.regions()] == ["aside-f", "aside-k"]
    assert SetAside.from_entries(contradictory, []).planned is contradictory
