"""A shelf that cannot stand as observed is reported, never planned on as if it were the shelf."""
from __future__ import annotations

import json
import re
import math

from shelfpick.console.cli import main
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.planner import make_plan
from tests.planning.sim_scenes import cube, stacked


def _floating() -> Scene:
    """`f` is seen 30 cm above the floor with nothing under it."""
    return Scene(Shelf(), (cube("a", -0.3, 0.1), cube("f", 0.2, 0.4))).hide_depths()


def _on_its_edge() -> Scene:
    """A cube balanced on one edge (turned 45 deg about the pull axis): it cannot stand so."""
    q = (math.cos(math.pi / 8), 0.0, math.sin(math.pi / 8), 0.0)
    h = 0.1 * math.sqrt(2)
    return Scene(Shelf(), (Box("edge", (0.2, 0.2, 0.2), (0.0, 0.12, h), q), cube("a", -0.3, 0.1))).hide_depths()


def test_a_floating_box_makes_the_plan_unsafe_and_names_the_box():
    plan = make_plan(_floating(), "extract", "a", samples=2, seed=0)
    check = plan.extra["scene_check"]
    assert check["stands_as_seen"] is False and not plan.safe
    assert [p["box"] for p in check["problems"]] == ["f"]
    assert re.match(r"drops 0\.(29|30)\d m while settling", check["problems"][0]["what"])
    assert check["redrawn"] >= 2   # every draw of both samples was tried again


def test_a_cube_balanced_on_its_edge_is_reported():
    plan = make_plan(_on_its_edge(), "extract", "a", samples=2, seed=0)
    check = plan.extra["scene_check"]
    assert not check["stands_as_seen"] and not plan.safe
    assert [p["box"] for p in check["problems"]] == ["edge"]
    assert "falls over at a small knock" in check["problems"][0]["what"]


def _seen_above(gap: float, x: float = 0.0) -> Scene:
    """`b` is seen `gap` above the top of `a` (shifted `x` sideways), `c` stands alone."""
    return Scene(Shelf(), (cube("a", 0.0, 0.1), cube("b", x, 0.3 + gap), cube("c", 0.4, 0.1))).hide_depths()


def test_a_box_seen_a_few_cm_above_its_support_stands():
    """Faces are measured to about 1 cm each, and a stack's heights add up their errors: a box
    seen 4.5 cm above the box it rests on drops onto it, and the shelf stands as seen (issue 32:
    at 1 cm of face error 31 of the judge's 40 shelves were called "cannot stand as seen")."""
    plan = make_plan(_seen_above(0.045), "extract", "c", samples=2, seed=0)
    check = plan.extra["scene_check"]
    assert check["stands_as_seen"] and check["problems"] == [], check
    assert plan.safe


def test_a_box_seen_far_above_its_support_does_not_stand():
    check = make_plan(_seen_above(0.12), "extract", "c", samples=2, seed=0).extra["scene_check"]
    assert not check["stands_as_seen"]
    assert [p["box"] for p in check["problems"]] == ["b"]
    assert re.match(r"drops 0\.1[12]\d m while settling", check["problems"][0]["what"])


def test_a_box_that_drops_and_slides_off_its_support_does_not_stand():
    """Dropping is forgiven, sliding or tipping off is not: `b` seen 4 cm up and 12 cm past the
    edge of `a` (its centre of mass outside) falls sideways."""
    check = make_plan(_seen_above(0.04, x=0.12), "extract", "c", samples=2, seed=0).extra["scene_check"]
    assert not check["stands_as_seen"] and [p["box"] for p in check["problems"]] == ["b"]


def test_a_shelf_that_stands_says_so():
    plan = make_plan(stacked().hide_depths(), "extract", "c", samples=2, seed=0)
    check = plan.extra["scene_check"]
    assert check["stands_as_seen"] and check["problems"] == [] and check["samples_not_standing"] == 0
    assert plan.safe and plan.sequence == ("c",)


def test_the_command_line_warns_and_writes_the_check_into_the_plan(tmp_path, capsys):
    path = tmp_path / "floating.json"
    _floating().save(path)
    out = tmp_path / "plan.json"
    assert main(["plan", str(path), "--target", "a", "--samples", "2", "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert re.search(r"does not stand as observed: box f drops 0\.(29|30)\d m", err)
    doc = json.loads(out.read_text())
    assert doc["safe"] is False and doc["scene_check"]["problems"][0]["box"] == "f"


def test_the_check_is_the_same_whatever_the_worker_count():
    """The pool keeps its worlds in worker processes; the check (repairs included) comes back all the same."""
    scene = Scene(Shelf(), (cube("a", -0.3, 0.1), cube("b", -0.3, 0.28), cube("f", 0.2, 0.4))).hide_depths()
    one = make_plan(scene, "extract", "a", samples=2, seed=1, workers=1).extra["scene_check"]
    two = make_plan(scene, "extract", "a", samples=2, seed=1, workers=2).extra["scene_check"]
    assert one == two and [p["box"] for p in one["problems"]] == ["f"]
    assert any("'b'" in r for r in one["repairs"])   # b overlapped a by 2 cm and was lifted
