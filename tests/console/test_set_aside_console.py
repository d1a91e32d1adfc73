"""The console plans around perceived faces no world can hold, as `shelfpick plan` does
(planning/set_aside.py), instead of "planning failed" on the whole capture. Real workflow,
planners, predictor and SQLite; the capture's perceived scene is put in place of a camera's."""
from __future__ import annotations

import pytest


@pytest.fixture
def wf(tmp_path):
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    store = SessionStore(tmp_path / "aside.sqlite")
    w = Workflow(None, store, lambda truth, seed: None, "pw", samples=2)
    yield w
    w.close()
    store.close()


def captured(wf, scene, target):
    """`scene` as a capture's perceived scene, `target` selected (what `capture` leaves behind)."""
    with wf._lock:
        wf._generation += 1
        wf._set(scene=scene, target=target, plans={}, error=None)


def test_the_console_plans_away_from_set_aside_faces_and_refuses_a_set_aside_target(wf, contradictory):
    from shelfpick.planning.plan import scene_hash

    scene = contradictory
    captured(wf, scene, "c")
    st = wf.plan("extract", wait=True)
    assert st.error is None
    phys = st.plans["physics"].plan
    assert phys.safe          # c stands far from the faces set aside: judged as on any shelf
    assert phys.sequence == ("c",) and [a["boxes"] for a in phys.extra["set_aside"]] == [["f", "k"]]
    assert phys.provenance["scene_hash"] == scene_hash(scene)      # bound to the capture, not the planned scene
    assert st.plans["heuristic"].plan.extra["set_aside"] == phys.extra["set_aside"]
    wf.select_target("n")                     # the kept predictor plans the next target of this capture
    st = wf.plan("extract", wait=True)
    n = st.plans["physics"].plan
    assert "n" in n.sequence and not n.safe and n.extra["set_aside"] == phys.extra["set_aside"]
    wf.select_target("f")
    st = wf.plan("extract", wait=True)
    assert not st.plans and st.error.startswith("planning failed: f was set aside")


def test_the_plan_table_names_the_faces_set_aside_escaped():
    from shelfpick.console.web.markdown import results_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State
    from shelfpick.planning.plan import Plan, StepPrediction

    aside = [{"boxes": ["b*6", "b_7"], "why": "box 'b*6' and box 'b_7' overlap by 0.164 m"}]
    plan = Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0"),), False, {}, 0, {"set_aside": aside})
    md = results_markdown(State(plans={"physics": PlanEntry(plan, plan.content_hash())}))
    row = next(ln for ln in md.splitlines() if ln.startswith("| faces set aside as unexplained matter |"))
    assert "b&#42;6 and b&#95;7&#58; box &#39;b&#42;6&#39; and box &#39;b&#95;7&#39; overlap by 0&#46;164 m" in row
    plain = Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0"),), True, {}, 0, {})
    assert "set aside" not in results_markdown(State(plans={"physics": PlanEntry(plain, plain.content_hash())}))


def test_the_preview_keeps_a_set_aside_box_where_it_was_seen_and_hides_a_pulled_one(server):
    """Set-aside faces are in no sample world, so no preview frame records them: they stay drawn as
    perceived (with their `?`), while a box a frame lacks because it was pulled is hidden."""
    import numpy as np

    from shelfpick.console.web.scene_view import Keyframe, apply_keyframe, draw_boxes
    from shelfpick.perception.scene import Box, Scene, Shelf

    scene = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (-0.3, 0.12, 0.1)), Box("b1", (0.2, 0.2, 0.2), (0.0, 0.12, 0.1)),
                            Box("b6", (0.2, 0.2, 0.2), (0.3, 0.12, 0.1), extra={"perceived": {"contradicted": True}})))
    nodes = draw_boxes(server.scene, scene)
    frame = Keyframe(0, "b1", 0.1, {"b0": ((-0.3, 0.1, 0.1), (1.0, 0.0, 0.0, 0.0))}, ())
    apply_keyframe(server, nodes, frame, scene.shelf, None, {"b0", "b1"})
    assert nodes["b0"].box.visible and np.allclose(nodes["b0"].box.position, (-0.3, 0.1, 0.1))
    assert not nodes["b1"].box.visible                       # pulled: gone from the frame
    assert nodes["b6"].box.visible and np.allclose(nodes["b6"].box.position, (0.3, 0.12, 0.1))
    apply_keyframe(server, nodes, frame, scene.shelf)        # without it, as before: hidden
    assert not nodes["b6"].box.visible


def test_set_aside_faces_are_drawn_as_grey_matter_in_place_of_their_boxes_until_no_plan_sets_them_aside(server):
    """A set-aside face is no box the planner knows stands: the 3D view draws what it planned with
    (grey matter from the face back to the wall, where planning puts it) and hides the box, also
    through a preview's reset; once no plan sets it aside, the box is back and the matter gone."""
    from types import SimpleNamespace

    from shelfpick.console.web.segmentation_view import set_aside_entries
    from shelfpick.console.web.panels import ShelfDrawing
    from shelfpick.console.web.scene_view import UNEXPLAINED_COLOR, reset_boxes
    from shelfpick.perception.scene import Box, Scene, Shelf
    from shelfpick.planning.plan import Plan, StepPrediction
    from shelfpick.planning.set_aside import SetAside, set_aside
    from shelfpick.planning.unexplained import obstacles

    scene = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (-0.3, 0.1, 0.1)), Box("b6", (0.2, 0.2, 0.2), (0.2, 0.1, 0.1)),
                            Box("b7", (0.2, 0.2, 0.2), (0.3, 0.1, 0.1))))
    why = "box 'b6' and box 'b7' overlap by 0.100 m"
    aside = [{"boxes": ["b6", "b7"], "why": why}]
    plans = [Plan("extract", "b0", p, ("b0",), (StepPrediction("b0"),), False, {}, 0, {"set_aside": aside})
             for p in ("physics", "heuristic")]
    entries = set_aside_entries(plans)
    assert SetAside.from_entries(scene, entries).entries == tuple(aside)   # both planners' record: drawn once
    drawing = ShelfDrawing(SimpleNamespace(scene=server.scene))     # the view draws on its client's scene
    drawing.draw(scene, None, False, lambda bid: None)
    drawing.mark(None, set(), None, scene, entries)
    assert not drawing.nodes["b6"].box.visible and not drawing.nodes["b7"].box.visible
    assert drawing.nodes["b0"].box.visible
    solids = [h for h in drawing.aside_nodes if getattr(h, "opacity", None)]
    labels = sorted(h.text for h in drawing.aside_nodes if hasattr(h, "text"))
    assert labels == ["aside-b6 ?", "aside-b7 ?"]
    expected = obstacles(Scene(Shelf(), (scene.boxes[0],),
                               unexplained=set_aside(scene, ("b6", "b7"), why).unexplained))
    assert sorted(tuple(round(c, 6) for c in h.position) for h in solids) == \
        sorted(tuple(round(c, 6) for c in centre) for _, _, centre in expected)
    assert all(tuple(h.color) == UNEXPLAINED_COLOR for h in solids) and len(solids) == len(expected) > 0
    reset_boxes(server, drawing.nodes, scene, drawing.hidden)           # a preview back at its start
    assert not drawing.nodes["b6"].box.visible and drawing.nodes["b0"].box.visible
    drawing.mark(None, set(), None, scene, [])                          # plans gone (a new target)
    assert drawing.nodes["b6"].box.visible and drawing.nodes["b7"].box.visible and drawing.aside_nodes == []
    assert set_aside_entries([Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0"),), True, {}, 0,
                                   {"set_aside": [{"boxes": "b6"}]})]) == []      # malformed: nothing drawn


def test_a_replayed_session_draws_the_faces_its_plans_set_aside_and_going_live_draws_them_no_more(tmp_path):
    """A stored session's plans carry what they set aside: its replay draws the same grey matter in
    place of those boxes; back to live (no capture), nothing of it is left drawn."""
    from session_fixture import replaying
    from test_store import tiny_capture

    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.perception.scene import Box, Scene, Shelf
    from shelfpick.planning.plan import Plan, StepPrediction

    scene = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (-0.3, 0.1, 0.1)), Box("b6", (0.2, 0.2, 0.2), (0.2, 0.1, 0.1)),
                            Box("b7", (0.2, 0.2, 0.2), (0.3, 0.1, 0.1))))
    aside = [{"boxes": ["b6", "b7"], "why": "box 'b6' and box 'b7' overlap by 0.100 m"}]
    store = SessionStore(tmp_path / "aside-replay.sqlite")
    sid = store.new_session("files:aside", tiny_capture(), scene, None, None)
    store.add_plan(sid, Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0"),), False, {}, 0,
                             {"set_aside": aside}))
    try:
        with replaying(store, sid) as view:
            assert view.drawing.hidden == {"b6", "b7"} and view.drawing.nodes["b0"].box.visible
            assert sorted(h.text for h in view.drawing.aside_nodes if hasattr(h, "text")) == ["aside-b6 ?", "aside-b7 ?"]
            view._live(None)
            assert view.drawing.hidden == set() and view.drawing.aside_nodes == []
    finally:
        store.close()
