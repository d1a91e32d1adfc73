"""The console workflow on a tiny shelf built in code: real rendering, perception,
planners, PyBullet robot and SQLite file; no viser."""
from __future__ import annotations

import sqlite3
import threading
import time

import pytest

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.scene import Box, Scene, Shelf

PASS = "open sesame"


def small_scene() -> Scene:
    """Three boxes standing apart on the floor: easy to perceive, three steps to clear."""
    from shelfpick.perception.render import default_camera

    return Scene(Shelf(), (Box("b0", (0.25, 0.25, 0.23), (-0.30, 0.13, 0.115)),
                           Box("b1", (0.20, 0.20, 0.20), (0.00, 0.11, 0.10)),
                           Box("b2", (0.20, 0.20, 0.25), (0.30, 0.10, 0.125))), default_camera())


class CodeShelfSource:
    """A camera in front of a shelf built in code (rendered like the demo source)."""

    def __init__(self, scene: Scene, fail: bool = False) -> None:
        self.name = "code-shelf"
        self.scene = scene
        self.fail = fail
        self.n = 0

    def capture(self):
        from shelfpick.console.sources import Frame
        from shelfpick.perception.render import render

        if self.fail:
            raise PerceptionError("camera: no device connected")
        self.n += 1
        # one fixed rendering seed: the test is about the workflow, not about perception noise
        return Frame(render(self.scene, seed=2), self.scene, f"code-shelf-{self.n}")


def sim_factory(delay: float = 0.0):
    from shelfpick.console.robot.drivers import open_robot

    def make(truth, seed):
        return open_robot(f"sim?delay={delay}" if delay else "sim", truth=truth, seed=seed)
    return make


@pytest.fixture
def make_wf(tmp_path):
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    made = []

    def build(scene: Scene | None = None, robot=None, fail: bool = False, db=None, timeout: float = 5.0,
              workers: int = 1):
        store = SessionStore(db or tmp_path / f"s{len(made)}.sqlite", timeout=timeout)
        wf = Workflow(CodeShelfSource(scene or small_scene(), fail), store, robot or sim_factory(),
                      PASS, samples=2, seed=0, workers=workers)
        made.append((wf, store))
        return wf

    yield build
    for wf, s in made:
        wf.close()
        s.close()


def bottom_left(scene: Scene) -> str:
    return min((b for b in scene.boxes if b.position[0] < 0), key=lambda b: b.position[2]).id


def planned(wf, task="extract"):
    from shelfpick.console.workflow.machine import WorkflowError  # noqa: F401

    st = wf.capture()
    assert st.error is None, st.error
    if task == "extract":
        wf.select_target(bottom_left(st.scene))
    wf.plan(task, wait=True)
    st = wf.state
    assert st.error is None and set(st.plans) == {"physics", "heuristic"}, st.error
    return st


def test_full_cycle_records_everything(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    seen: list = []
    wf.add_listener(lambda s: seen.append(s.version))
    st = planned(wf)
    phys = st.plans["physics"]
    target = st.target
    assert phys.plan.sequence[-1] == target
    assert phys.plan.safe and len(phys.preview) == len(phys.plan.sequence)
    assert any(r.frames for r in phys.preview)
    with pytest.raises(WorkflowError, match="wrong supervisor passphrase"):
        wf.approve(phys.hash, "guess", "mallory")
    with pytest.raises(WorkflowError, match="not a plan for the current capture"):
        wf.approve("0123456789abcdef", PASS, "sue")
    with pytest.raises(WorkflowError, match="nothing approved"):
        wf.execute()
    wf.approve(phys.hash, PASS, "sue")
    wf.execute(wait=True)
    st = wf.state
    assert st.robot == "done", (st.robot, st.error, st.outcome)
    assert st.outcome.completed == phys.plan.sequence and st.needs_recapture
    with pytest.raises(WorkflowError, match="capture"):
        wf.plan("extract")
    end = time.monotonic() + 5
    while seen[-1] != wf.state.version and time.monotonic() < end:
        time.sleep(0.05)
    assert seen == sorted(set(seen)) and seen[-1] == wf.state.version   # in order, up to the last

    rec = wf.store.load_session(st.session_id)
    assert {p.plan.planner for p in rec.plans} == {"physics", "heuristic"}
    assert [(d["decision"], d["who"], d["plan_hash"]) for d in rec.decisions] == [("approve", "sue", phys.hash)]
    kinds = [e["kind"] for e in rec.robot_events]
    assert "auth_refused" in kinds and kinds.count("done") == len(phys.plan.sequence)
    assert rec.outcome["ok"] and rec.outcome["completed"] == list(phys.plan.sequence)
    assert any(p.preview and p.preview[0].get("frames") for p in rec.plans)


def test_new_capture_invalidates_approval(make_wf):
    """An approval holds the run lock: a capture is refused until Stop withdraws it; after the
    new capture the old plan is not approvable."""
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf)
    old = st.plans["physics"].hash
    wf.approve(old, PASS, "sue")
    assert wf.state.approved == old
    with pytest.raises(WorkflowError, match="capture refused: plan .* is approved"):
        wf.capture()
    wf.stop("op")
    assert wf.state.approved is None and "withdrawn" in wf.state.message
    wf.capture()
    st = wf.state
    assert st.approved is None and not st.plans
    with pytest.raises(WorkflowError, match="nothing approved"):
        wf.execute()
    with pytest.raises(WorkflowError, match="not a plan for the current capture"):
        wf.approve(old, PASS, "sue")


def test_reject_needs_reason_and_is_recorded(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf, "clear")
    h = st.plans["heuristic"].hash
    with pytest.raises(WorkflowError, match="reason"):
        wf.reject(h, PASS, "sue", "  ")
    wf.reject(h, PASS, "sue", "too risky")
    rec = wf.store.load_session(st.session_id)
    assert [(d["decision"], d["reason"]) for d in rec.decisions] == [("reject", "too risky")]


def test_stop_aborts_remaining_steps(make_wf):
    wf = make_wf(robot=sim_factory(delay=1.5))
    st = planned(wf, "clear")
    seq = st.plans["physics"].plan.sequence
    assert len(seq) == 3
    acked = threading.Event()
    wf.add_listener(lambda s: acked.set() if any(e.kind == "ack" for e in s.robot_events) else None)
    wf.approve(st.plans["physics"].hash, PASS, "sue")
    t0 = time.monotonic()
    wf.execute()
    assert acked.wait(30)
    wf.stop("op")
    st = wf.wait_robot(30)
    assert time.monotonic() - t0 < 3 * 1.5 + 20
    assert st.robot == "stopped" and st.needs_recapture
    assert len(st.outcome.completed) < len(seq)
    rec = wf.store.load_session(st.session_id)
    assert rec.outcome is not None and rec.outcome["stopped"] and not rec.outcome["ok"]
    assert "aborted" in [e["kind"] for e in rec.robot_events]


def test_unknown_target_and_concurrent_planning_refused(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = wf.capture()
    with pytest.raises(WorkflowError, match="unknown box id 'nope'"):
        wf.select_target("nope")
    wf.plan("clear")
    with pytest.raises(WorkflowError, match="already running"):
        wf.plan("clear")
    st = wf.wait_planning(120)
    assert not st.planning and set(st.plans) == {"physics", "heuristic"}


def test_faults_become_messages(make_wf, tmp_path):
    wf = make_wf(fail=True)
    st = wf.capture()
    assert "camera" in st.error and st.scene is None
    empty = Scene(Shelf(), (), small_scene().camera)
    wf = make_wf(scene=empty)
    st = wf.capture()
    assert "no boxes" in st.error and st.session_id is not None
    assert wf.store.load_session(st.session_id).n_boxes == 0


def test_locked_database_is_a_message_not_a_crash(make_wf, tmp_path):
    db = tmp_path / "locked.sqlite"
    wf = make_wf(db=db, timeout=0.3)
    other = sqlite3.connect(db, timeout=0.1)
    other.execute("BEGIN EXCLUSIVE")
    try:
        st = wf.capture()
        assert st.scene is not None and st.scene.boxes      # the console keeps working
        assert st.error and "database" in st.error
    finally:
        other.rollback()
        other.close()
    st = wf.capture()
    assert st.error is None and st.session_id is not None


@pytest.mark.parametrize("fault", ["drop_after", "refuse_steps"])
def test_tcp_robot_disconnect_or_refusal_is_recorded(make_wf, fault):
    """A real robot-side TCP server that drops the connection after one step / refuses step 2."""
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.robotsim.controller import RobotController

    kw = {"drop_after": 1} if fault == "drop_after" else {"refuse_steps": [1]}
    with RobotController(**kw).start() as ctl:
        wf = make_wf(robot=lambda truth, seed: open_robot(ctl.url, truth=truth, seed=seed))
        st = planned(wf, "clear")
        phys = st.plans["physics"]
        wf.approve(phys.hash, PASS, "sue")
        st = wf.execute(wait=True)
    assert st.robot == "failed" and st.needs_recapture and st.error.startswith("robot:")
    assert st.outcome.completed == phys.plan.sequence[:1]          # step 1 done, nothing after
    rec = wf.store.load_session(st.session_id)
    kinds = [e["kind"] for e in rec.robot_events]
    assert kinds.count("done") == 1
    assert ("disconnected" if fault == "drop_after" else "error") in kinds
    assert rec.outcome["completed"] == list(phys.plan.sequence[:1]) and not rec.outcome["ok"]
    sent = [m for m in ctl.received("step")] if hasattr(ctl, "received") else []
    assert len({m.get("step") for m in sent}) <= 2                  # never past the failing step


def test_unsafe_plan_needs_explicit_risk_acceptance(make_wf, monkeypatch):
    """When no safe plan exists the least risky one may run only if the supervisor
    accepts its predicted risk in so many words; the decision records that."""
    import dataclasses

    import shelfpick.planning.planner as planner_module
    from shelfpick.console.workflow.machine import WorkflowError

    real = planner_module.make_plan

    def unsafe(*args, **kwargs):
        return dataclasses.replace(real(*args, **kwargs), safe=False)

    monkeypatch.setattr(planner_module, "make_plan", unsafe)
    wf = make_wf()
    st = wf.capture()
    wf.select_target(bottom_left(st.scene))
    wf.plan("extract", wait=True)
    st = wf.state
    assert st.error.startswith("no safe plan")
    phys = st.plans["physics"]
    assert not phys.plan.safe
    with pytest.raises(WorkflowError, match="predicted unsafe.*Accept predicted risk"):
        wf.approve(phys.hash, PASS, "sue")
    assert wf.state.approved is None
    wf.approve(phys.hash, PASS, "sue", accept_risk=True)
    assert wf.state.approved == phys.hash
    assert wf.state.decisions[-1]["reason"].startswith("accepted predicted risk")
    rec = wf.store.load_session(st.session_id)
    assert any(d["decision"] == "approve" and (d.get("reason") or "").startswith("accepted predicted risk")
               for d in rec.decisions)


def test_planning_on_two_processes_gives_the_same_plans(make_wf):
    """The console plans on a pool of processes (shelfpick console --workers): same plans."""
    one, two = make_wf(), make_wf(workers=2)
    a, b = planned(one), planned(two)
    for planner in ("physics", "heuristic"):
        assert a.plans[planner].hash == b.plans[planner].hash
        assert a.plans[planner].plan.predicted == b.plans[planner].plan.predicted


def test_close_announces_the_last_change_and_ends_the_notifier(make_wf):
    import threading

    def notifiers() -> int:
        return sum(1 for t in threading.enumerate() if t.name == "shelfpick-notify" and t.is_alive())

    before = notifiers()
    wf = make_wf()
    seen: list[int] = []
    wf.add_listener(lambda s: seen.append(s.version))
    last = wf._set(message="one").version
    wf.close()
    assert seen and seen[-1] == last            # nothing announced is dropped by close
    assert notifiers() == before                # this workflow's thread has ended
    again = threading.Event()
    wf.add_listener(lambda s: again.set() if s.message == "two" else None)
    wf._set(message="two")                      # a change after close is still announced
    assert again.wait(5)
    wf.close()
    assert notifiers() == before


def stack_scene() -> Scene:
    """A box on another and one beside them: the bottom one has a blocker."""
    from shelfpick.perception.render import default_camera

    return Scene(Shelf(), (Box("b0", (0.25, 0.25, 0.23), (-0.20, 0.13, 0.115)),
                           Box("b1", (0.20, 0.20, 0.20), (-0.20, 0.11, 0.33)),
                           Box("b2", (0.20, 0.20, 0.25), (0.25, 0.10, 0.125))), default_camera())


@pytest.mark.parametrize("workers", [1, 2])
def test_a_second_plan_of_the_same_capture_reuses_the_worlds_and_gives_the_same_plans(make_wf, workers):
    def plans_of(st):
        return {k: (e.plan.sequence, e.plan.safe, e.plan.predicted) for k, e in st.plans.items()}

    wf = make_wf(stack_scene(), workers=workers)
    st = wf.capture()
    assert st.error is None, st.error
    low, high = sorted(st.scene.ids, key=lambda b: st.scene.box(b).position[2])[0], \
        max(st.scene.ids, key=lambda b: st.scene.box(b).position[2])
    wf.select_target(high)
    wf.plan("extract", wait=True)
    kept = wf._kept[1]
    wf.select_target(low)
    second = wf.plan("extract", wait=True)
    assert wf._kept[1] is kept                   # the same sample worlds answered the second plan
    assert len(second.plans["physics"].plan.sequence) >= 2, second.plans["physics"].plan

    fresh = make_wf(stack_scene())            # one process: the plans do not depend on workers
    fresh.capture()
    fresh.select_target(low)
    alone = fresh.plan("extract", wait=True)
    assert plans_of(second) == plans_of(alone)   # same seed, same plans, whatever was planned before

    wf.capture()                                 # a new capture: its plans get new worlds
    wf.select_target(low)
    wf.plan("extract", wait=True)
    assert wf._kept[1] is not kept and kept.sims == []      # the old one was closed


def test_a_kept_predictor_whose_worker_died_is_replaced_not_used(make_wf):
    wf = make_wf(stack_scene(), workers=2)
    st = wf.capture()
    wf.select_target(st.scene.ids[0])
    first = wf.plan("extract", wait=True)
    kept = wf._kept[1]
    worker = kept._workers[0][0]
    worker.kill()                                 # an idle worker killed between two plans
    assert not kept.usable()
    again = wf.plan("extract", wait=True)
    assert again.error == first.error and wf._kept[1] is not kept
    assert {k: e.plan.sequence for k, e in again.plans.items()} == {k: e.plan.sequence for k, e in first.plans.items()}


def test_close_releases_the_sources_camera_even_when_the_camera_is_already_gone(tmp_path):
    """The console's shutdown (ConsoleApp.stop -> Workflow.close) hands a camera back, as a
    RealSense source's `close` does; a camera that fails to close does not stop the shutdown."""
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    class HeldCamera(CodeShelfSource):
        """A source that holds its device from the first capture until `close`."""

        def __init__(self, scene: Scene, broken: bool = False) -> None:
            super().__init__(scene)
            self.held, self.broken = False, broken

        def capture(self):
            self.held = True
            return super().capture()

        def close(self) -> None:
            if self.broken:
                raise OSError("device disconnected")
            self.held = False

    for broken in (False, True):
        store = SessionStore(tmp_path / f"cam-{broken}.sqlite")
        cam = HeldCamera(small_scene(), broken)
        wf = Workflow(cam, store, sim_factory(), PASS, samples=2, seed=0)
        try:
            wf.capture()
            assert cam.held
            wf.close()
            assert cam.held == broken
        finally:
            wf.close()
            store.close()


def test_close_while_a_plan_runs_leaves_its_clients_to_it_and_closes_them_after(make_wf):
    """close() (the console's shutdown) disconnected every Bullet client of the pool, also those a
    plan worker was simulating with: the worker then failed with "Not connected to physics server"
    (seen driving the console in Chromium). Now the running plan finishes on its clients and the
    worker closes the pool when it is done."""
    wf = make_wf()
    wf.capture()
    planned(wf)                                 # the pool exists; its clients are reused below
    pool = wf._clients
    wf.plan("extract")                          # a second plan, in the background
    wf.close()
    st = wf.wait_planning(120)
    assert st.error is None and not st.planning, st.error
    assert set(st.plans) >= {"physics", "heuristic"}
    assert pool._closed and not pool._all       # closed after the plan, every client disconnected
