"""The viser layer without a browser: host policy, the plan table, replay records, preview timelines."""
from __future__ import annotations

import html
import re
import urllib.request

import numpy as np
import pytest

from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.plan import Plan, StepPrediction


def two_plans():
    from shelfpick.console.workflow.machine import PlanEntry

    phys = Plan("extract", "b0", "physics", ("b1", "b0"),
                (StepPrediction("b1", 0.0), StepPrediction("b0", 0.0)), True,
                {"planning_s": 1.5, "setup_s": 0.5, "verify_s": 0.25}, 0,
                {"search": {"samples": 10, "worlds": 10, "verified_worlds": 20}})
    heur = Plan("extract", "b0", "heuristic", ("b2", "b1", "b0"),
                (StepPrediction("b2", 0.0), StepPrediction("b1", 0.5, 0.0, ("b3",)), StepPrediction("b0", 0.0)),
                False, {"planning_s": 0.01}, 0)
    return {"physics": PlanEntry(phys, phys.content_hash()), "heuristic": PlanEntry(heur, heur.content_hash())}


def test_non_local_host_needs_a_passphrase():
    from shelfpick.console.web.app import ConsoleError, check_host
    from shelfpick.console.cli import main

    check_host("127.0.0.1", None)
    check_host("127.0.0.1", "a")                       # local: any passphrase
    check_host("0.0.0.0", "correct horse battery")
    with pytest.raises(ConsoleError, match="0.0.0.0.*passphrase"):
        check_host("0.0.0.0", None)
    for short in ("a", " ", "            ", "eleven char"):
        with pytest.raises(ConsoleError, match="at least 12 characters"):
            check_host("0.0.0.0", short)
    assert main(["console", "--host", "0.0.0.0", "--port", "0"]) == 2


def test_results_table_side_by_side():
    from shelfpick.console.web.app import results_markdown
    from shelfpick.console.workflow.machine import State

    md = results_markdown(State(plans=two_plans()))
    lines = md.splitlines()
    assert lines[0] == "| | physics | heuristic |"
    row = {ln.split("|")[1].strip().replace("\u00a0", " "): [c.strip().replace("\u00a0", " ")
                                                             for c in ln.split("|")[2:4]]
           for ln in lines[2:] if ln.startswith("|")}
    assert row["sequence"] == ["b1 → b0", "b2 → b1 → b0"]
    assert row["boxes removed"] == ["2", "3"]
    # one step a line, each item kept whole (no-break spaces) so a narrow column never splits one
    assert row["collapse risk per step"] == ["1. b1 0%<br>2. b0 0%", "1. b2 0%<br>2. b1 50%<br>3. b0 0%"]
    assert row["est. execution (12.5 s/box)"] == ["25.0 s", "37.5 s"]
    assert row["planning time"] == ["2.25 s", "0.01 s"]
    assert row["predicted safe"] == ["yes", "**NO**"]
    assert row["sample worlds behind the risks"] == ["20 (10 searched; 10 more asked to decide whether it is safe)", "—"]
    assert "sample worlds: shelves the camera cannot tell apart" in md
    assert "Planning" in results_markdown(State(planning=True, progress_text="physics"))


def test_preview_timeline_from_results_and_json_hides_parked_boxes():
    from shelfpick.console.web.scene_view import timeline, visible_pose

    shelf = Shelf()
    frames = [(0.0, {"a": ((0, 0.1, 0.1), (1, 0, 0, 0)), "b": ((0.3, 0.1, 0.1), (1, 0, 0, 0))}),
              (0.5, {"a": ((0, -0.4, 0.1), (1, 0, 0, 0)), "b": ((0.3, 0.1, 0.1), (1, 0, 0, 0))}),
              (1.0, {"a": ((0, -50.0, -5.0), (1, 0, 0, 0)), "b": ((0.3, 0.1, 0.05), (0.9, 0.1, 0, 0))})]
    as_json = [{"box": "a", "collapsed": ["b"], "frames": [[t, {k: [list(p), list(q)] for k, (p, q) in f.items()}]
                                                          for t, f in frames]},
               {"box": "b", "collapsed": [], "frames": [[0.0, {"b": [[0.3, 0.1, 0.05], [1, 0, 0, 0]]}]]}]
    tl = timeline(as_json)
    assert [k.step for k in tl] == [0, 0, 0, 1]
    # recorded times (real pace), a 0.3 s pause between two pulls
    assert tl[-1].t == pytest.approx(1.3) and tl[1].t == pytest.approx(0.5) and tl[0].collapsed == ("b",)
    assert visible_pose(tl[1].poses["a"], shelf) and not visible_pose(tl[2].poses["a"], shelf)
    assert len(timeline(as_json * 50, max_frames_per_step=2)) <= 50 * 2 * 2


def test_app_serves_and_replays_a_stored_session(tmp_path):
    from shelfpick.console.web.app import ConsoleApp, record_view
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from shelfpick.perception.render import default_camera, render

    scene = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)),), default_camera())
    store = SessionStore(tmp_path / "s.sqlite")
    cap = render(scene, seed=0, noise=False)
    sid = store.new_session("test", cap, scene, scene, np.zeros_like(cap.rgb), {})
    plans = two_plans()
    for e in plans.values():
        store.add_plan(sid, e.plan, [{"box": "b0", "collapsed": [], "frames": [[0.0, {"b0": [[0, 0.1, 0.1], [1, 0, 0, 0]]}]]}])
    h = plans["physics"].hash
    store.add_decision(sid, h, "approve", "sue")
    store.set_outcome(sid, {"plan": h, "planner": "physics", "sequence": ["b1", "b0"], "completed": ["b1"],
                            "ok": False, "error": "step 2 (b0): boxes collapsed: b3",
                            "steps": [{"step": 0, "box": "b1", "status": "done"},
                                      {"step": 1, "box": "b0", "status": "error"}]})
    view = record_view(store.load_session(sid))
    assert view.rgb.shape == cap.rgb.shape and view.scene.ids == ("b0",)
    assert set(view.plans) == {"physics", "heuristic"} and view.target == "b0"
    md = html.unescape(view.summary_md)      # what the browser shows (outside text is entity-escaped)
    assert f"approve `{h}` by sue" in md and "completed: b1" in md and "collapsed: b3" in md
    assert "| 2 | b0 | 0% |" in md
    assert re.search(r"started \d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC ·", md), md  # not the raw ISO text

    wf = Workflow(None, store, lambda truth, seed: None, "pw")
    app = ConsoleApp(wf, port=0)
    try:
        assert app.port > 0 and app.url.startswith("http://127.0.0.1:")
        with urllib.request.urlopen(app.url, timeout=10) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
        assert app.load_replay(sid).id == sid
    finally:
        app.stop()
        store.close()


def test_a_step_risk_that_is_a_collision_is_shown_beside_the_collapse():
    """After a hold the `continue` plan showed every step at 0% and 'max risk 50%': the 50% was one
    step's collision chance, which the table did not show. Now the step says so, and the row says
    what the maximum is of."""
    from dataclasses import replace

    from shelfpick.console.web.app import results_markdown
    from shelfpick.console.workflow.machine import State
    from shelfpick.planning.plan import StepPrediction

    plans = two_plans()
    e = plans["physics"]
    plan = replace(e.plan, predicted=(StepPrediction("b1", 0.0, 0.5, ()), StepPrediction("b0", 0.0, 0.0, ())))
    md = results_markdown(State(plans={"physics": replace(e, plan=plan)})).replace("\u00a0", " ")
    assert "| collapse risk per step | 1. b1 0%, collision 50%<br>2. b0 0% |" in md
    assert "| max risk (collapse or collision) | 50% |" in md


def test_a_view_whose_browser_went_away_or_whose_server_stops_draws_nothing_more(tmp_path):
    """A state change on another thread (a plan finishing) must not draw on a connection already
    closed: a closed view renders nothing, a render under way ends before `close` returns, and
    the app's stop and a browser's disconnect close the view."""
    import threading
    from types import SimpleNamespace

    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.web.app import ClientView, ConsoleApp
    from shelfpick.console.workflow.machine import Workflow

    store = SessionStore(tmp_path / "closed.sqlite")
    wf = Workflow(None, store, lambda truth, seed: None, "pw")
    app = ConsoleApp(wf, port=0)
    try:
        gone, stays, third = (ClientView(app, app.server) for _ in range(3))
        app.views.update({1: gone, 2: stays, 3: third})
        with wf._lock:
            wf._set(message="first")
        app._on_state(wf.state)
        before = gone.operator.status.content
        app._disconnect(SimpleNamespace(client_id=1))
        assert gone.closed and not stays.closed and 1 not in app.views
        with wf._lock:
            wf._set(message="second, after the browser left")
        gone.render(wf.state)                     # as _on_state does with a view it listed before the pop
        stays.render(wf.state)
        assert gone.operator.status.content == before != stays.operator.status.content
        answer = gone.operator.answers.handle.content
        gone.operator.answers.clicked("Capture", lambda: None)()    # a click's answer after it left
        gone._live(None)
        assert gone.operator.answers.handle.content == answer and gone.operator.status.content == before
        order: list[str] = []
        with stays.lock:                          # a render under way on another thread ...
            closer = threading.Thread(target=lambda: (stays.close(), order.append("closed")))
            closer.start()
            closer.join(0.2)
            order.append("render ended")
        closer.join(5)
        assert order == ["render ended", "closed"]  # ... ends before close returns
        assert not third.closed
    finally:
        app.stop()
        store.close()
    assert third.closed                           # the app's stop closed it
