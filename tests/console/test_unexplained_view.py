"""The console's 3D view of unexplained matter (issue 31 item 2), on a real viser server."""
from __future__ import annotations

import pytest

from shelfpick.perception.scene import Box, Scene, Shelf, Unexplained


def _scene(*regions: Unexplained) -> Scene:
    return Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (0.0, 0.12, 0.1)),), unexplained=regions or None)


def test_regions_are_drawn_where_planning_puts_them_grey_and_labelled(server):
    from shelfpick.console.web.scene_view import UNEXPLAINED_COLOR, draw_unexplained
    from shelfpick.planning.unexplained import obstacles

    u = Unexplained("u0", (0.12, 0.02, 0.02), (0.30, 0.05, 0.20), 4000, 0.03, ((0.12, 0.30, 0.02, 0.20, 0.02),))
    scene = _scene(u)
    handles = draw_unexplained(server.scene, scene)
    (_, half, centre), = obstacles(scene)
    solid, edge, label = handles
    assert solid.dimensions == pytest.approx(tuple(2 * h for h in half))
    assert tuple(solid.position) == pytest.approx(centre) == tuple(edge.position)
    assert tuple(solid.color) == UNEXPLAINED_COLOR and solid.opacity == pytest.approx(0.35)
    assert edge.wireframe
    assert label.text == "u0 ?"
    for h in handles:       # the panel removes them on the next draw
        h.remove()


def test_a_scene_without_regions_draws_nothing(server):
    from shelfpick.console.web.scene_view import draw_unexplained

    assert draw_unexplained(server.scene, _scene()) == []
    assert draw_unexplained(server.scene, Scene(Shelf(), ())) == []


def test_the_plan_table_says_what_touches_unexplained_matter():
    from shelfpick.console.web.markdown import results_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State
    from shelfpick.planning.plan import Plan, StepPrediction

    touched = Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0"),), False, {}, 0,
                   {"unexplained": {"regions": ["u0"], "touched": ["step 1: pulling b0 touches unexplained matter u0"]}})
    clear = Plan("extract", "b0", "heuristic", ("b0",), (StepPrediction("b0"),), True, {}, 0,
                 {"unexplained": {"regions": ["u0"], "touched": []}})
    plans = {"physics": PlanEntry(touched, touched.content_hash()), "heuristic": PlanEntry(clear, clear.content_hash())}
    md = results_markdown(State(plans=plans))
    row = next(ln for ln in md.splitlines() if ln.startswith("| unexplained matter |"))
    assert "pulling b0 touches unexplained matter u0" in row and "not touched" in row   # escaped: outside text
    plain = Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0"),), True, {}, 0, {})
    md = results_markdown(State(plans={"physics": PlanEntry(plain, plain.content_hash())}))
    assert "unexplained matter" not in md          # a scene without regions: no row
