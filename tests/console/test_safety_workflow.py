"""The console's state machine under pressure: one run lock from approval to the end of the run,
one Stop that reaches it, audit first, the passphrase throttle, never-re-send keyed by session and
capture, a target change dropping plans, scene-check problems. Real PyBullet, SQLite, TCP sockets."""
from __future__ import annotations

import sqlite3
import threading
import time

import pytest

from safety_kit import (TALLY, BlockingSource, CountingRobots, HonestPeer, fault, judge_session,  # noqa: F401
                        judge_stop)
from test_workflow import PASS, CodeShelfSource, bottom_left, make_wf, planned, sim_factory, small_scene  # noqa: F401


def approvals(wf, sid) -> list:
    return [d for d in wf.store.load_session(sid).decisions if d["decision"] == "approve"]


# ------------------------------------------------------------------ item 1: one run, one stop
def test_approve_and_execute_refused_while_a_capture_runs(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf, "clear")
    h = st.plans["physics"].hash
    src = BlockingSource(wf.source)
    wf.source = src
    src.gate.clear()
    src.entered.clear()
    t = threading.Thread(target=wf.capture)
    t.start()
    try:
        assert src.entered.wait(10) and wf.state.capturing and wf.state.phase == "capturing"
        fault()
        with pytest.raises(WorkflowError, match="capture is running|not a plan for the current capture"):
            wf.approve(h, PASS, "sue")
        with pytest.raises(WorkflowError, match="nothing approved"):
            wf.execute()
        with pytest.raises(WorkflowError, match="capture is already running"):
            wf.capture()
        with pytest.raises(WorkflowError, match="capture is running"):
            wf.plan("clear")
    finally:
        src.gate.set()
        t.join(30)
    assert wf.state.robot == "idle" and not approvals(wf, st.session_id)


def test_an_approval_holds_the_run_lock_until_stop_withdraws_it(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf, "clear")
    h = st.plans["physics"].hash
    wf.approve(h, PASS, "sue")
    assert wf.state.phase == "approved"
    for action, call in [("capture", wf.capture), ("planning", lambda: wf.plan("clear")),
                         ("changing the target", lambda: wf.select_target(st.scene.ids[0])),
                         ("approval", lambda: wf.approve(st.plans["heuristic"].hash, PASS, "ann"))]:
        with pytest.raises(WorkflowError, match=f"{action} refused: plan {h} is approved"):
            call()
    wf.stop("op")
    assert wf.state.approved is None and wf.state.phase == "planned"
    with pytest.raises(WorkflowError, match="nothing approved"):
        wf.execute()
    rec = wf.store.load_session(st.session_id)
    assert [e["kind"] for e in rec.robot_events] == ["stop"] and rec.outcome is None


def test_stop_reaches_the_run_and_is_stored_as_stopped(make_wf):
    robots = CountingRobots(delay=1.0)
    wf = make_wf(robot=robots)
    st = planned(wf, "clear")
    h = st.plans["physics"].hash
    acked = threading.Event()
    wf.add_listener(lambda s: acked.set() if any(e.kind == "ack" for e in s.robot_events) else None)
    wf.approve(h, PASS, "sue")
    wf.execute()
    assert acked.wait(20)
    fault()
    wf.stop("op")
    st = wf.wait_robot(20)
    judge_stop(st.robot == "stopped" and len(robots.moved) == 1)
    assert st.robot == "stopped" and len(robots.moved) == 1
    rec = wf.store.load_session(st.session_id)
    assert rec.status == "stopped" and rec.outcome["stopped"] and not rec.outcome["ok"]
    assert rec.outcome["stopped_by"] == "op"
    judge_session(wf.store, st.session_id, robots.moved)


@pytest.mark.parametrize("round_", range(3))
def test_racing_approve_capture_execute_stop_never_runs_two(make_wf, round_):
    """Two supervisors approve, an operator captures, two execute loops and a Stop, all at once."""
    from shelfpick.console.workflow.machine import WorkflowError

    robots = CountingRobots(delay=0.2)
    wf = make_wf(robot=robots)
    st = planned(wf, "clear")
    sid, h = st.session_id, st.plans["physics"].hash
    go = threading.Barrier(6)
    errors: list[str] = []

    def guarded(fn):
        def run():
            go.wait()
            try:
                fn()
            except WorkflowError as exc:
                errors.append(str(exc))
        return run

    def execute_loop():
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            try:
                wf.execute()
            except WorkflowError:
                pass
            time.sleep(0.005)

    def stop_later():
        time.sleep(0.05 * round_)
        wf.stop("op")

    threads = [threading.Thread(target=guarded(f)) for f in (
        lambda: wf.approve(h, PASS, "sue"), lambda: wf.approve(h, PASS, "ann"), wf.capture,
        execute_loop, execute_loop, stop_later)]
    fault(4)
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    wf.wait_robot(30)
    assert robots.max_active <= 1 and robots.runs <= 1
    events = wf.store.load_session(sid).robot_events
    withdrawn = sum(1 for e in events if e["kind"] == "stop" and not e["detail"]["running"])
    assert len(approvals(wf, sid)) - withdrawn <= 1          # a second approval only after Stop withdrew
    judge_session(wf.store, sid, robots.moved)
    if robots.runs:
        judge_stop(wf.state.robot in ("stopped", "done"))   # a stop before execute withdrew, after aborted
    assert TALLY["unapproved"] == TALLY["unrecorded"] == 0


def test_two_supervisors_approving_at_once_store_exactly_one(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf, "clear")
    for attempt in range(5):
        go = threading.Barrier(2)
        won, lost = [], []

        def approve(who):
            go.wait()
            try:
                wf.approve(st.plans["physics"].hash, PASS, who)
                won.append(who)
            except WorkflowError as exc:
                lost.append(str(exc))

        ts = [threading.Thread(target=approve, args=(w,)) for w in ("sue", "ann")]
        fault()
        [t.start() for t in ts]
        [t.join(30) for t in ts]
        assert len(won) == 1 and len(lost) == 1 and "refused" in lost[0]
        assert len(approvals(wf, st.session_id)) == attempt + 1     # one more each round, never two
        wf.stop("op")                                              # withdraw, try again


# ------------------------------------------------------------------ item 5: passphrase
def test_wrong_passphrases_are_throttled_and_every_refusal_reads_the_same(make_wf):
    from shelfpick.console.workflow.machine import AUTH_REFUSED, Throttle, WorkflowError

    now = [1000.0]
    wf = make_wf()
    wf.throttle = Throttle(clock=lambda: now[0])
    st = planned(wf, "clear")
    h = st.plans["physics"].hash
    texts = set()

    def attempt(pw, client):
        try:
            wf.approve(h, pw, "mallory", client=client)
            return None
        except WorkflowError as exc:
            texts.add(str(exc))
            return str(exc)

    t0 = time.monotonic()
    threads = [threading.Thread(target=lambda i=i: [attempt(f"guess{i}-{k}", "browser-1") for k in range(100)])
               for i in range(20)]
    fault()                                          # one flood of 2,000 wrong tries
    [t.start() for t in threads]
    [t.join(60) for t in threads]
    assert time.monotonic() - t0 < 30
    compared = 2000 - wf.throttle.throttled
    assert compared <= 3, compared                  # two free typos, then the browser waits
    # right passphrase, still in the wait: the very same refusal, nothing approved
    assert attempt(PASS, "browser-1") is not None and wf.state.approved is None
    # another browser: the overall throttle has not tripped yet (3 wrong < 5) -> it may approve
    assert texts == {f"approval refused: {AUTH_REFUSED}"}
    # many browsers: the global throttle stops them too
    for i in range(10):
        attempt("nope", f"browser-x{i}")
    assert attempt(PASS, "browser-fresh") == f"approval refused: {AUTH_REFUSED}"
    now[0] += 3600                                   # the waits are over
    assert attempt(PASS, "browser-1") is None and wf.state.approved == h
    refused = [e for e in wf.store.load_session(st.session_id).robot_events if e["kind"] == "auth_refused"]
    assert 1 <= len(refused) <= 20                   # compared tries recorded, the flood is not


def test_a_right_passphrase_is_not_told_apart_by_a_different_refusal(make_wf):
    """Refusals that do not depend on the passphrase come first, so they read the same either way."""
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf, "clear")
    msgs = []
    for pw in (PASS, "wrong"):
        with pytest.raises(WorkflowError) as exc:
            wf.approve("0123456789abcdef", pw, "sue")
        msgs.append(str(exc.value))
    assert msgs[0] == msgs[1] and "not a plan for the current capture" in msgs[0]


# ------------------------------------------------------------------ item 8: target after planning
def test_changing_the_target_drops_the_plans(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf, "extract")
    old = st.plans["physics"].hash
    other = next(b for b in st.scene.ids if b != st.target)
    wf.select_target(other)
    st = wf.state
    assert st.target == other and not st.plans and "dropped" in st.message
    fault()
    with pytest.raises(WorkflowError, match="not a plan for the current capture"):
        wf.approve(old, PASS, "sue")


def test_scene_check_problems_are_shown_stored_and_need_risk_acceptance(make_wf, monkeypatch):
    import dataclasses

    import shelfpick.planning.planner as planner_module
    from shelfpick.console.workflow.machine import WorkflowError

    real = planner_module.make_plan
    what = 'floats 0.30 m above <b>what holds it</b> [x](http://evil.example/)'

    def floating(*a, **k):
        p = real(*a, **k)
        extra = {**p.extra, "scene_check": {"stands_as_seen": False, "problems": [{"box": p.sequence[0], "what": what}]}}
        return dataclasses.replace(p, safe=False, extra=extra)

    monkeypatch.setattr(planner_module, "make_plan", floating)
    wf = make_wf()
    st = wf.capture()
    wf.plan("clear", wait=True)
    st = wf.state
    assert st.scene_problems and st.scene_problems[0]["what"] == what
    assert st.error.startswith("the shelf does not stand as seen")
    fault()
    with pytest.raises(WorkflowError, match="does not stand as seen.*Accept predicted risk"):
        wf.approve(st.plans["physics"].hash, PASS, "sue")
    wf.approve(st.plans["physics"].hash, PASS, "sue", accept_risk=True)
    rec = wf.store.load_session(st.session_id)
    stored = [p.plan.extra["scene_check"] for p in rec.plans if p.plan.planner == "physics"][0]
    assert stored["problems"][0]["what"] == what
    assert "scene problems" in [d for d in rec.decisions if d["decision"] == "approve"][0]["reason"]


# ------------------------------------------------------------------ item 4: audit first
def lock_db(path):
    other = sqlite3.connect(path, timeout=0.1, isolation_level=None, check_same_thread=False)
    other.execute("BEGIN EXCLUSIVE")
    return other


def test_locked_database_refuses_the_approval_and_the_page_keeps_saying_so(make_wf, tmp_path):
    from shelfpick.console.workflow.machine import WorkflowError

    robots = CountingRobots()
    wf = make_wf(robot=robots, db=tmp_path / "a.sqlite", timeout=0.3)
    st = planned(wf, "clear")
    other = lock_db(tmp_path / "a.sqlite")
    fault()
    try:
        with pytest.raises(WorkflowError, match="approval refused: the decision could not be recorded"):
            wf.approve(st.plans["physics"].hash, PASS, "sue")
    finally:
        other.rollback()
        other.close()
    with pytest.raises(WorkflowError, match="nothing approved"):
        wf.execute()
    wf.select_target(st.scene.ids[0])          # other actions clear `error`, not the audit warning
    assert wf.state.audit and "could not record the approval" in wf.state.audit
    assert robots.runs == 0 and not approvals(wf, st.session_id)


def test_locked_database_at_start_refuses_to_start_the_robot(make_wf, tmp_path):
    from shelfpick.console.workflow.machine import WorkflowError

    robots = CountingRobots()
    wf = make_wf(robot=robots, db=tmp_path / "b.sqlite", timeout=0.3)
    st = planned(wf, "clear")
    wf.approve(st.plans["physics"].hash, PASS, "sue")
    other = lock_db(tmp_path / "b.sqlite")
    fault()
    t0 = time.monotonic()
    try:
        with pytest.raises(WorkflowError, match="robot not started"):
            wf.execute()
    finally:
        other.rollback()
        other.close()
    assert time.monotonic() - t0 < 3 and robots.runs == 0
    assert wf.state.robot == "idle" and wf.state.audit


def test_full_database_means_nothing_can_be_approved(make_wf, tmp_path):
    """The disk fills up (SQLite's max_page_count): the capture or the plans cannot be recorded,
    so nothing can be approved and the robot never moves; the page says so."""
    from shelfpick.console.workflow.machine import WorkflowError

    robots = CountingRobots()
    wf = make_wf(robot=robots, db=tmp_path / "c.sqlite")
    planned(wf, "clear")
    with wf.store._lock:
        pages = wf.store._db.execute("PRAGMA page_count").fetchone()[0]
        wf.store._db.execute(f"PRAGMA max_page_count={pages}")    # the disk is full now
    fault()
    st = wf.capture()
    wf.plan("clear", wait=True)
    st = wf.state
    assert st.audit and "full" in st.audit
    with pytest.raises(WorkflowError, match="no session record|was not recorded"):
        wf.approve(st.plans["physics"].hash, PASS, "sue")
    assert robots.runs == 0 and wf.state.audit


@pytest.mark.parametrize("how", ["read-only", "locked"])
def test_a_robot_event_that_cannot_be_committed_stops_the_run(make_wf, tmp_path, how):
    robots = CountingRobots(delay=1.0)
    wf = make_wf(robot=robots, db=tmp_path / "d.sqlite", timeout=0.3)
    st = planned(wf, "clear")
    assert len(st.plans["physics"].plan.sequence) == 3
    wf.approve(st.plans["physics"].hash, PASS, "sue")
    hold = []

    def on_ack(s):
        if not hold and any(e.kind == "ack" for e in s.robot_events):
            if how == "read-only":
                with wf.store._lock:
                    wf.store._db.execute("PRAGMA query_only=1")
                hold.append(None)
            else:
                hold.append(lock_db(tmp_path / "d.sqlite"))
    wf.add_listener(on_ack)
    fault()
    t0 = time.monotonic()
    wf.execute()
    st = wf.wait_robot(30)
    if how == "locked" and hold and hold[0] is not None:
        hold[0].rollback()
        hold[0].close()
    else:
        with wf.store._lock:
            wf.store._db.execute("PRAGMA query_only=0")
    assert time.monotonic() - t0 < 6
    judge_stop(len(robots.moved) == 1)
    assert len(robots.moved) == 1 and st.robot == "stopped"     # step 2 never started
    assert st.audit and "robot was stopped" in st.error
    rec = wf.store.load_session(st.session_id)
    assert [e["kind"] for e in rec.robot_events][:2] == ["start", "ack"]   # the move is on record
    judge_session(wf.store, st.session_id, robots.moved)


# ------------------------------------------------------------------ item 2: never re-send, by capture
def tcp_wf(make_wf, peer):
    from shelfpick.console.robot.drivers import open_robot
    return make_wf(robot=lambda truth, seed: open_robot(peer.url, truth=truth, seed=seed))


def run_once(wf, accept: bool = False):
    st = wf.capture()
    wf.plan("clear", wait=True)
    st = wf.state
    e = st.plans["physics"]
    wf.approve(e.hash, PASS, "sue", accept_risk=accept)
    wf.execute(wait=True)
    return wf.state, e


def test_a_new_capture_with_the_same_sequence_is_a_new_run():
    peer = HonestPeer()
    try:
        _check_new_run(peer)
    finally:
        peer.close()


def _check_new_run(peer):
    import tempfile
    from pathlib import Path

    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from shelfpick.console.robot.drivers import open_robot

    with tempfile.TemporaryDirectory() as d:
        store = SessionStore(Path(d) / "n.sqlite")
        wf = Workflow(CodeShelfSource(small_scene()), store,
                      lambda truth, seed: open_robot(peer.url, truth=truth, seed=seed), PASS, samples=2)
        try:
            st1, e1 = run_once(wf)
            assert st1.robot == "done" and len(peer.steps) == 3
            fault()
            st2, e2 = run_once(wf)
            assert e2.hash == e1.hash and st2.session_id != st1.session_id
            assert st2.robot == "done" and st2.outcome.ok and len(peer.steps) == 6     # the robot was asked
            assert [s[2] for s in peer.steps[3:]] == [0, 1, 2]
            judge_session(store, st2.session_id, [(e2.hash, i) for i in range(3)])
        finally:
            wf.close()
            store.close()


@pytest.mark.parametrize("fault_kind", ["refuse", "drop_after_ack"])
def test_after_an_error_or_unknown_step_a_new_capture_sends_again(tmp_path, fault_kind):
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    # first connection: step 0 done, then step 1 refused / acknowledged and the link drops
    peer = HonestPeer(script=lambda conn, step: fault_kind if conn == 0 and step == 1 else "ok")
    store = SessionStore(tmp_path / "e.sqlite")
    wf = None
    try:
        wf = Workflow(CodeShelfSource(small_scene()), store,
                      lambda truth, seed: open_robot(peer.url, truth=truth, seed=seed), PASS, samples=2)
        st1, e1 = run_once(wf)
        fault()
        assert st1.robot == "failed" and st1.outcome.completed == e1.plan.sequence[:1]
        states = store.step_states(st1.session_id, e1.hash)
        assert states[0][0] == "done"
        assert states[1][0] == ("failed" if fault_kind == "refuse" else "unknown")
        st2, e2 = run_once(wf)                  # the shelf seen again: same sequence, new capture
        assert e2.hash == e1.hash
        assert st2.robot == "done", (st2.error, st2.outcome)
        assert [s[2] for s in peer.steps if s[0] >= 1] == [0, 1, 2]     # step 0 sent again
    finally:
        if wf is not None:
            wf.close()
        peer.close()
        store.close()


def test_step_states_survive_a_restart_and_an_unknown_step_refuses_only_that_capture(tmp_path):
    """Keyed by session (capture) and plan, from the database: a fresh store sees the same."""
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow, WorkflowError, PlanEntry
    from shelfpick.console.workflow.state import RunLock
    from shelfpick.planning.plan import Plan

    from test_store import tiny_capture, tiny_scene

    db = tmp_path / "r.sqlite"
    s = SessionStore(db)
    sid = s.new_session("t", tiny_capture(), tiny_scene(), None, None)
    plan = Plan("clear", None, "physics", ("b0", "b1"))
    h = s.add_plan(sid, plan)
    s.add_robot_event(sid, h, "ack", 0, "b0")
    s.add_robot_event(sid, h, "done", 0, "b0")
    s.add_robot_event(sid, h, "ack", 1, "b1")
    s.add_robot_event(sid, h, "disconnected", 1, "b1", {"code": "DISCONNECTED"})
    s.close()
    s = SessionStore(db)                                  # "restart"
    assert s.step_states(sid, h) == {0: ("done", "b0"), 1: ("unknown", "b1")}
    sid2 = s.new_session("t", tiny_capture(), tiny_scene(), None, None)
    assert s.step_states(sid2, h) == {}                   # a new capture starts clean
    wf = Workflow(None, s, lambda t, seed: None, PASS)
    run = RunLock(h, PlanEntry(plan, h), sid, 0, "sue")
    with pytest.raises(WorkflowError, match=r"step 2 \(b1\) .* unknown outcome for this capture"):
        wf._steps_before(run)
    assert wf._steps_before(RunLock(h, PlanEntry(plan, h), sid2, 0, "sue")) == {}
    wf.close()
    s.close()


def test_a_flood_of_wrong_passphrases_does_not_lock_out_the_supervisor_at_their_own_browser(make_wf):
    """Issue 30: an attacker kept the overall brake engaged and the supervisor was refused 6 of 6.
    Now the supervisor's browser, connected before the flood and without wrong tries of its own,
    is judged by its own record; the attacker's browsers, old or new, stay braked."""
    from shelfpick.console.workflow.machine import AUTH_REFUSED, Throttle, WorkflowError

    now = [1000.0]
    wf = make_wf()
    wf.throttle = Throttle(clock=lambda: now[0])
    st = planned(wf, "clear")
    h = st.plans["physics"].hash
    wf.throttle.connected("browser-sup")
    wf.throttle.connected("browser-evil-old")
    now[0] += 1.0

    def attempt(pw, client):
        try:
            wf.approve(h, pw, "x", accept_risk=True, client=client, planner="physics")
            return None
        except WorkflowError as exc:
            return str(exc)

    fault()
    approved = 0
    for round_ in range(6):
        for i in range(20):                                      # the flood, from fresh browsers
            wf.throttle.connected(f"browser-evil{round_}-{i}")
            attempt("guess", f"browser-evil{round_}-{i}")
            now[0] += 0.05
        assert attempt(PASS, f"browser-late{round_}") == f"approval refused: {AUTH_REFUSED}"   # braked
        if attempt(PASS, "browser-sup") is None:
            approved += 1
            wf.stop("op")                                        # withdraw, and the flood goes on
    assert approved == 6
    for _ in range(3):                                           # an old browser of the attacker's: its
        attempt("guess", "browser-evil-old")                     # own record ends its say
    assert attempt(PASS, "browser-evil-old") == f"approval refused: {AUTH_REFUSED}"
