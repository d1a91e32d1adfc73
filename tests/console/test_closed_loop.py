"""Closed loop through the real console: a step that collapses a neighbour holds the robot.

Real viser server (ConsoleApp on a free port, a view registered on it), real
SQLite file, the reference TCP robot (its own PyBullet world), rendering and
perception. The shelf is a generated `lean` shelf: a standing long box leans
on a column, which perception reports as upright, so the highest-first plan's
first pull is predicted safe and drops the leaning box in the robot's world.

Seed 8 of `generate("lean", seed, 8)` was picked by trying seeds 0-63
(a /tmp script; issue 11): its first pull is predicted safe and, in the
robot's own world, drops two boxes by 10 and 27 cm (most other seeds hold on
what turned out to be perception alone: the robot's world had not moved, the
reason the console now looks twice before holding). An extraction
re-planned from the capture after the hold, of a free box far from the fallen
ones, runs to the end. On seed 2 every re-plan's first pull really moves the
fallen boxes again, so the console rightly holds it. Without the look after
each step the same run is not held (the second test).
"""
from __future__ import annotations

import time

import pytest

from test_workflow import PASS

pytestmark = pytest.mark.slow


class CameraOnRobotShelf:
    """A demo camera that, after a step, renders the robot's own world (the robot runs elsewhere)."""

    def __init__(self, scene, controller) -> None:
        from shelfpick.console.sources import DemoSource

        self.demo = DemoSource([("lean", scene)], seed=2)
        self.name = "camera-on-robot-shelf"
        self.controller = controller

    def capture(self):
        return self.demo.capture()

    def look_again(self, world, step, attempt=0):
        return self.demo.look_again(world if world is not None else self.controller.world(), step, attempt)


class CameraThatDoesNotLookAgain:
    """The same camera without `look_again`: the console runs the plan open loop."""

    def __init__(self, scene, controller) -> None:
        self.camera = CameraOnRobotShelf(scene, controller)
        self.name = "camera-without-look"

    def capture(self):
        return self.camera.capture()


def make_console(tmp_path, camera, seed=None):
    from shelfpick.console.web.app import ClientView, ConsoleApp
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.robotsim.controller import RobotController
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from shelfpick.perception.render import default_camera
    from shelfpick.planning.shelves import generate

    truth = generate("lean", LEAN_SEED if seed is None else seed, 8)
    truth = type(truth)(truth.shelf, truth.boxes, default_camera())
    ctl = RobotController(truth=truth).start()
    store = SessionStore(tmp_path / "closed.sqlite")
    wf = Workflow(camera(truth, ctl), store,
                  lambda t, seed: open_robot(ctl.url, truth=t, seed=seed), PASS, samples=2)
    app = ConsoleApp(wf, port=0)
    view = ClientView(app, app.server)
    app.views[4242] = view
    return wf, store, ctl, view, app


LEAN_SEED = 8


@pytest.fixture
def lean_console(tmp_path):
    wf, store, ctl, view, app = make_console(tmp_path, CameraOnRobotShelf)
    yield wf, store, ctl, view
    app.stop()
    store.close()
    ctl.close()


@pytest.fixture
def open_loop_console(tmp_path):
    wf, store, ctl, view, app = make_console(tmp_path, CameraThatDoesNotLookAgain)
    yield wf, store, ctl, view
    app.stop()
    store.close()
    ctl.close()


def settle(wf, timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = wf.state.version
        time.sleep(0.3)
        if wf.state.version == v:
            return


def test_collapse_holds_before_step_two_and_a_new_plan_completes(lean_console):
    wf, store, ctl, view = lean_console
    first = wf.capture()
    wf.plan("clear", wait=True)
    heur = wf.state.plans["heuristic"]
    assert heur.plan.predicted[0].collapse_prob == 0.0        # the planner did not see it coming
    wf.approve(heur.hash, PASS, "sup", accept_risk=True)
    wf.execute(wait=True)
    st = wf.state
    # held after step 1: the robot was sent exactly one step of that plan
    assert st.robot == "held", (st.robot, st.message, st.error)
    assert [s for h, s, _ in ctl.executed if h == heur.hash] == [0]
    assert len(ctl.received("step")) == 1
    dev = st.deviation
    assert dev is not None and dev.verification.step == 0 and not dev.verification.within
    moved = [d for d in dev.verification.boxes if d.status != "ok"]
    assert moved, dev.verification
    # recorded: the held session has the step's predicted and observed shelves and status held
    rec = store.load_session(first.session_id)
    assert rec.status == "held" and len(rec.verifications) == 1
    assert rec.verifications[0]["predicted"] is not None and rec.verifications[0]["observed"] is not None
    assert not rec.verifications[0]["within"]
    # the look is the current capture, a new session linked to the held one
    assert st.session_id != first.session_id and st.phase == "held"
    assert store.load_session(st.session_id).perception["verification_of"]["session"] == first.session_id
    # shown: the page's deviation text and red outlines on the boxes that differ, blue predicted outlines
    settle(wf)
    assert "Robot held before step 2" in view.deviation_md.content
    differ = {d.observed for d in moved if d.observed}
    assert differ and all(view.nodes[b].risk.visible for b in differ if b in view.nodes)
    assert getattr(view, "predicted_nodes", [])
    # nothing can run without a new approval
    with pytest.raises(Exception):
        wf.execute()
    # a new plan from the new capture: approved, runs verified step by step, completes. Its target:
    # a box with nothing on it, in the column farthest (left-right) from every box that differs
    still = [b for b in wf.state.scene.boxes if b.id in {d.observed for d in dev.verification.boxes
                                                         if d.status == "ok"}]
    fallen = [b for b in wf.state.scene.boxes if b.id in differ]
    free = [b for b in still if not any(o is not b and abs(o.position[0] - b.position[0]) < (o.size[0] + b.size[0]) / 2
                                        and o.position[2] > b.position[2] for o in wf.state.scene.boxes)]
    top = max(free, key=lambda b: min(abs(b.position[0] - f.position[0]) for f in fallen))
    wf.select_target(top.id)
    wf.plan("extract", wait=True)
    phys = wf.state.plans["physics"]
    replanned = wf.state.session_id
    wf.approve(phys.hash, PASS, "sup", accept_risk=True)
    wf.execute(wait=True)
    st = wf.state
    # the new plan ran under the new approval to the end, each step looked at and recorded (a
    # difference after the last step is evidence only: nothing is left to hold)
    assert st.robot == "done", (st.robot, st.message, st.error)
    assert st.outcome is not None and st.outcome.plan == phys.hash
    assert st.outcome.completed == phys.plan.sequence and phys.plan.sequence[-1] == top.id
    assert [v.step for v in st.verifications] == list(range(len(phys.plan.sequence)))
    assert all(v.within for v in st.verifications[:-1]), [v.summary() for v in st.verifications]
    rec2 = store.load_session(replanned)    # (a difference after the last step makes its look current)
    assert rec2.status == "done" and rec2.outcome["plan"] == phys.hash
    assert [r["step"] for r in rec2.verifications] == list(range(len(phys.plan.sequence)))
    assert [(d["decision"], d["plan_hash"]) for d in rec2.decisions] == [("approve", phys.hash)]


def test_without_the_look_the_same_run_is_not_held(open_loop_console):
    """The counterfactual: no look after the step, no hold, nothing verified or recorded as such."""
    wf, store, ctl, view = open_loop_console
    first = wf.capture()
    wf.plan("clear", wait=True)
    heur = wf.state.plans["heuristic"]
    wf.approve(heur.hash, PASS, "sup", accept_risk=True)
    wf.execute(wait=True)
    st = wf.state
    assert st.robot != "held" and st.deviation is None and not st.verifications, (st.robot, st.message)
    # here only the robot's own report (the reference controller simulates, so it sees the collapse)
    # stops the run: failed, no look, nothing to plan again from
    assert st.robot == "failed" and st.phase == "finished", (st.robot, st.phase)
    rec = store.load_session(first.session_id)
    assert rec.status != "held" and not rec.verifications


@pytest.fixture
def continue_console(tmp_path):
    """A console whose heuristic clearance was held with every box still to take seen, so that it
    offers `continue`: the first such lean shelf among CONTINUE_SEEDS. Which seeds do that moves with
    the shelf generator, the simulation and the look (23 did when this test was written; 6 and 29 do
    at e0724f3); a fixed seed made this test fail whenever one of them changed, for no fault of the
    behaviour under test (it failed so from the last stop on: seed 23 now ends `failed`)."""
    tried = []
    for seed in CONTINUE_SEEDS:
        (tmp_path / f"seed{seed}").mkdir()
        wf, store, ctl, view, app = make_console(tmp_path / f"seed{seed}", CameraOnRobotShelf, seed=seed)
        wf.capture()
        wf.plan("clear", wait=True)
        heur = wf.state.plans["heuristic"]
        wf.approve(heur.hash, PASS, "sup", accept_risk=True)
        wf.execute(wait=True)
        if wf.state.robot == "held" and set(wf.state.plans) == {"continue"}:
            break
        tried.append((seed, wf.state.robot))
        app.stop()
        store.close()
        ctl.close()
    else:
        pytest.fail(f"no lean seed in {CONTINUE_SEEDS} gives a held run that offers continue: {tried}")
    yield wf, store, ctl, view, heur
    app.stop()
    store.close()
    ctl.close()


CONTINUE_SEEDS = range(40)   # lean shelves tried in turn (see continue_console)


def test_a_supervisor_may_continue_the_held_plan(continue_console):
    """After a hold, `continue` (the rest of the held plan in the new capture's ids) is a plan of
    its own: offered, approved with the risk accepted, sent as a new run, verified step by step."""
    wf, store, ctl, view, heur = continue_console
    st = wf.state
    assert st.robot == "held" and set(st.plans) == {"continue"} and st.phase == "held", (st.robot, st.plans)
    k = st.deviation.verification.step
    cont = st.plans["continue"]
    assert len(cont.plan.sequence) == len(heur.plan.sequence) - k - 1
    assert cont.plan.extra["continues"]["plan"] == heur.hash and len(cont.shelves) == len(cont.plan.sequence)
    with pytest.raises(Exception):          # like every plan: not without accepting the risk
        wf.approve(cont.hash, PASS, "sup")
    held_run = ctl.received("step")[-1]["run"]
    wf.approve(cont.hash, PASS, "sup", accept_risk=True)
    wf.execute(wait=True)
    st = wf.state
    sent = [m for m in ctl.received("step") if m["plan"] == cont.hash]
    assert sent and {m["run"] for m in sent} != {held_run}          # a run of its own
    assert [m["box"] for m in sent] == list(cont.plan.sequence[:len(sent)])
    assert [v.step for v in st.verifications] == list(range(len(sent)))   # each sent step looked at
    # the rest of the held plan runs to the end, or is held again at the step the look disputes (both
    # are the console doing its job; which one is the shelf's: at e0724f3 seed 6 is held again at b3,
    # seed 29 runs to the end)
    if st.robot == "done":
        assert st.outcome.plan == cont.hash and st.outcome.completed == cont.plan.sequence
        assert len(sent) == len(cont.plan.sequence)
    else:
        assert st.robot == "held" and st.deviation is not None, (st.robot, st.message, st.error)
        assert st.deviation.verification.step == len(sent) - 1
