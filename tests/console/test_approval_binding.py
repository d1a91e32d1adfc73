"""An approval is bound to the plan the supervisor reviewed (issue 30 item 2): planner + content hash,
as shown in that supervisor's browser. A plan that changed since is refused with a message, and
every acknowledgement (passphrase, risk tick) is cleared when the plan under review changes.
Real workflow, planners, SQLite and viser server (views as the app builds them per browser)."""
from __future__ import annotations

import time

import pytest

from safety_kit import fault
from test_workflow import PASS, CodeShelfSource, bottom_left, make_wf, planned, small_scene  # noqa: F401


def decisions(wf, sid) -> list:
    return wf.store.load_session(sid).decisions


def test_a_changed_plan_is_refused_and_the_approval_names_its_planner(make_wf):
    from shelfpick.console.workflow.machine import WorkflowError

    wf = make_wf()
    st = planned(wf, "extract")                     # the supervisor reviews the extraction plans
    reviewed = st.plans["physics"].hash
    wf.select_target(next(i for i in st.scene.ids if i != st.target))
    wf.plan("clear", wait=True)                     # the operator re-plans meanwhile
    now = wf.state.plans["physics"].hash
    assert now != reviewed
    fault()
    with pytest.raises(WorkflowError, match=f"the physics plan changed since it was shown \\({reviewed} "
                                            f"was reviewed, it is now plan {now}\\)"):
        wf.approve(reviewed, PASS, "sue", accept_risk=True, planner="physics")
    assert wf.state.approved is None and wf.state.robot == "idle"
    assert not decisions(wf, st.session_id) and wf.throttle.throttled == 0
    # identical physics and heuristic sequences share one hash: the planner chosen is the one named
    phys, heur = wf.state.plans["physics"], wf.state.plans["heuristic"]
    if heur.hash != phys.hash:
        pytest.skip("the planners differ on this shelf: nothing shared to name")
    with pytest.raises(WorkflowError, match="the heuristic plan changed"):
        wf.approve("0123456789abcdef", PASS, "sue", accept_risk=True, planner="heuristic")
    wf.approve(heur.hash, PASS, "sue", accept_risk=True, planner="heuristic")
    st = wf.state
    assert st.approval["planner"] == "heuristic" and st.decisions[-1]["planner"] == "heuristic"
    assert st.message == f"sue approved the heuristic plan {heur.hash}"
    assert [d["decision"] for d in decisions(wf, st.session_id)] == ["approve"]
    wf.stop("op")


@pytest.fixture
def app(tmp_path):
    from shelfpick.console.web.app import ClientView, ConsoleApp
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    store = SessionStore(tmp_path / "bind.sqlite")
    wf = Workflow(CodeShelfSource(small_scene()), store,
                  lambda truth, seed: open_robot("sim", truth=truth, seed=seed), PASS, samples=2)
    a = ConsoleApp(wf, port=0)
    view = ClientView(a, a.server)                  # one supervisor's view, as a browser gets it
    a.views[1000] = view
    yield a, wf, view
    a.stop()
    store.close()


def drawn(wf, view, timeout=20.0) -> None:
    """Wait until the view drew the latest state (the notifier draws every view in turn)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        st = wf.state
        if view.supervisor.reviewed == ((view.approve_plan.value, st.plans[view.approve_plan.value].hash)
                                        if view.approve_plan.value in (st.plans or {}) else None):
            time.sleep(0.3)
            if wf.state.version == st.version:
                return
        time.sleep(0.05)
    raise AssertionError("the supervisor view never drew the latest plans")


def test_acknowledgements_reset_when_the_plan_under_review_changes_and_a_stale_click_is_refused(app):
    from shelfpick.console.workflow.machine import WorkflowError

    a, wf, view = app
    told: list[str] = []
    view.notify = lambda title, body, color="red": told.append(body)     # what the browser is told
    st = planned(wf, "extract")
    drawn(wf, view)
    first = ("physics", st.plans["physics"].hash)
    assert view.supervisor.reviewed == first
    assert f"Deciding on:** the **physics** plan `{first[1]}`" in view.supervisor.sup_info.content
    view.passphrase.value, view.accept_risk.value = PASS, True     # typed and ticked for the 1-step plan
    wf.select_target(next(i for i in st.scene.ids if i != st.target))
    wf.plan("clear", wait=True)                                    # the operator re-plans
    drawn(wf, view)
    second = ("physics", wf.state.plans["physics"].hash)
    fault()
    assert view.supervisor.reviewed == second != first
    assert view.passphrase.value == "" and view.accept_risk.value is False   # nothing carried over
    view._approve(None)                                            # the click without typing again
    assert wf.state.approved is None and wf.state.robot == "idle"
    assert "type the supervisor passphrase" in told[-1]

    # the screen still shows the plan reviewed when the click arrives (its update not yet drawn):
    # the click carries that plan's hash and is refused by the workflow, with a message
    view.passphrase.value, view.accept_risk.value = PASS, True
    with view.lock:                                                 # this view draws nothing meanwhile
        wf.select_target(st.target)
        wf.plan("extract", wait=True)
        third = wf.state.plans["physics"].hash
        assert view.supervisor.reviewed == second and third != second[1]
        view._approve(None)
    assert wf.state.approved is None and wf.state.robot == "idle"
    assert f"the physics plan changed since it was shown ({second[1]} was reviewed" in told[-1]
    drawn(wf, view)
    assert view.supervisor.reviewed == ("physics", third) and view.passphrase.value == ""
    assert not decisions(wf, wf.state.session_id)

    # an attacker floods wrong passphrases from other browsers meanwhile: the overall brake engages
    # (a 16 s wait for them), but the supervisor's browser, open before the flood, keeps its say
    for i in range(10):
        with pytest.raises(WorkflowError, match="wrong supervisor passphrase"):
            wf.approve(third, "guess", "mallory", accept_risk=True, client=f"browser-evil{i}", planner="physics")
    assert wf.throttle.check("browser-new", lambda: True) is None   # a browser that came meanwhile waits
    view.passphrase.value, view.accept_risk.value = PASS, True     # typed again, for the plan shown
    view._approve(None)
    st = wf.wait_robot(60)
    assert st.outcome is not None and st.outcome.plan == third
    assert [(d["decision"], d["plan_hash"]) for d in decisions(wf, st.session_id)] == [("approve", third)]
