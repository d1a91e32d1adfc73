"""A realistic stored session for the replay and CLI tests: real render, real physics preview."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from shelfpick.console.store.sessions import SessionStore
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.plan import Plan, StepPrediction


def stack_scene() -> Scene:
    return Scene(Shelf(1.0, 0.3, 1.6), (
        Box("b0", (0.2, 0.2, 0.2), (0.0, 0.12, 0.1)),
        Box("b1", (0.2, 0.2, 0.2), (0.0, 0.12, 0.3)),
        Box("b2", (0.2, 0.2, 0.2), (0.3, 0.12, 0.1))))


def make_session(db: Path) -> tuple[int, dict]:
    """One session: capture, two plans (one with a recorded collapse preview), decisions, robot outcome."""
    from shelfpick.perception.render import render
    from shelfpick.planning.sim import ShelfSim

    scene = stack_scene()
    cap = render(scene, seed=3)
    overlay = cap.rgb.copy()
    overlay[cap.masks > 0] = (overlay[cap.masks > 0] * 0.5 + np.array([0, 120, 0])).astype(np.uint8)
    sim = ShelfSim(scene)
    try:
        bad = [sim.remove("b2", record=True).to_json(frames=True), sim.remove("b0", record=True).to_json(frames=True)]
    finally:
        sim.close()
    physics = Plan("extract", "b0", "physics", ("b1", "b0"),
                   (StepPrediction("b1"), StepPrediction("b0")), True, {"total": 2.5}, 0)
    heuristic = Plan("extract", "b0", "heuristic", ("b2", "b0"),
                     (StepPrediction("b2"), StepPrediction("b0", 1.0, 0.0, ("b1",))), True, {"total": 0.01}, 0)
    store = SessionStore(db)
    sid = store.new_session("demo:stack#0", cap, scene.hide_depths(0.05), scene, overlay,
                            {"warnings": ["box b1: depth unknown"], "timing": {"total": 0.4}})
    h_heur = store.add_plan(sid, heuristic, bad)
    h_phys = store.add_plan(sid, physics, None)
    store.add_decision(sid, h_heur, "reject", "supervisor-ana", "b1 would fall")
    store.add_decision(sid, h_phys, "approve", "supervisor-ana")
    store.add_robot_event(sid, h_phys, "ack", 0, "b1", {"true_box": "b1"})
    store.add_robot_event(sid, h_phys, "done", 0, "b1", {"collapsed": [], "true_box": "b1"})
    store.add_robot_event(sid, h_phys, "ack", 1, "b0", {"true_box": "b0"})
    store.add_robot_event(sid, h_phys, "done", 1, "b0", {"collapsed": [], "true_box": "b0"})
    store.set_outcome(sid, {"plan": h_phys, "planner": "physics", "sequence": ["b1", "b0"], "ok": True,
                            "completed": ["b1", "b0"], "error": None,
                            "steps": [{"step": 0, "box": "b1", "status": "done", "detail": {"collapsed": []}},
                                      {"step": 1, "box": "b0", "status": "done",
                                       "detail": {"collapsed": [], "displacement": {"b2": 0.002}}}]})
    store.close()
    return sid, {"rgb": cap.rgb, "physics": h_phys, "heuristic": h_heur, "preview": bad}


@contextmanager
def replaying(store: SessionStore, sid: int) -> Iterator:
    """A console view (a real ConsoleApp and viser server) replaying stored session `sid`."""
    from shelfpick.console.web.app import ClientView, ConsoleApp
    from shelfpick.console.workflow.machine import Workflow

    app = ConsoleApp(Workflow(None, store, lambda truth, seed: None, "pw"), port=0)
    try:
        view = ClientView(app, app.server)
        view.session_pick.options = (str(sid),)
        view.session_pick.value = str(sid)
        view._replay(None)
        yield view
    finally:
        app.stop()
