"""After a run ends the page says what became of it (h16): the plan panel no longer offers the
executed plan for review, the answer lines say how the run ended instead of an older click's
"started.", and the supervisor's decisions name the planner. Real viser server, real workflow,
SQLite file and TCP robot (tests/console/safety_kit.py's peer), the shelf of test_workflow."""
from __future__ import annotations

import html
import time

import pytest

from safety_kit import HonestPeer
from test_safety_app import MARKUP, literal
from test_workflow import PASS, CodeShelfSource, small_scene


class HeldLook(CodeShelfSource):
    """A camera whose look after a step still shows the box it took out: the robot is held."""

    def look_again(self, world, step, attempt=0):
        from shelfpick.console.sources import Frame
        from shelfpick.perception.render import render

        return Frame(render(self.scene, seed=2 + attempt), self.scene, f"look {step}.{attempt}")


@pytest.fixture
def console(tmp_path):
    """(app, workflow, one browser's view, robot peer); `script` picks the robot's answers and the
    source whether the look after a step holds the robot."""
    made = []

    def build(script=None, held=False):
        from shelfpick.console.web.app import ClientView, ConsoleApp
        from shelfpick.console.robot.drivers import open_robot
        from shelfpick.console.store.sessions import SessionStore
        from shelfpick.console.workflow.machine import Workflow

        peer = HonestPeer(script=script)
        store = SessionStore(tmp_path / f"run-end-{len(made)}.sqlite")
        source = (HeldLook if held else CodeShelfSource)(small_scene())
        wf = Workflow(source, store, lambda truth, seed: open_robot(peer.url, truth=truth, seed=seed), PASS,
                      samples=2)
        app = ConsoleApp(wf, port=0)
        view = ClientView(app, app.server)
        app.views[1000 + len(made)] = view
        made.append((app, store, peer))
        return app, wf, view, peer

    yield build
    for app, store, peer in made:
        app.stop()
        store.close()
        peer.close()


def until(cond, timeout=30.0, what="condition"):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.05)
    raise AssertionError(f"timed out waiting for {what}")


def answer_becomes(view, text: str, timeout: float = 10.0) -> None:
    """The Operator's answer line comes to read `text` (and says what it read when it does not)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if view.operator.answer.content == text:
            return
        time.sleep(0.05)
    raise AssertionError(f"the answer line reads {view.operator.answer.content!r}, not {text!r}")


def settle(wf, view, timeout=10.0):
    """Wait until the view drew the latest state (nothing changed for 0.3 s, and it was rendered)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = wf.state.version
        time.sleep(0.3)
        if wf.state.version == v:
            view.render(wf.state)     # the listener's render may still be on its way: draw it here too
            return
    raise AssertionError("the state kept changing")


def choose(view, planner: str, plan_hash: str) -> None:
    """The supervisor picks `planner` once it is offered, and until the view reviews it: a render of
    new plans rewrites the dropdown's options and keeps the choice it had, so a pick made in the same
    instant can come back to the old one (the page then shows, and approves, that one); pick again."""
    def reviewed() -> bool:
        if planner not in view.approve_plan.options:
            return False
        if view.approve_plan.value != planner:
            view.approve_plan.value = planner
        return view.supervisor.reviewed == (planner, plan_hash)

    until(reviewed, 10, f"the plan under review ({planner})")


def shown(markdown: str) -> str:
    """What the browser shows of a markdown text (entities decoded, word joiners dropped)."""
    return html.unescape(markdown).replace("\u2060", "")


def approve_and_run(wf, view, planner: str = "physics"):
    """The operator plans clearance with the button, the supervisor approves `planner`, the robot runs."""
    view.operator.press(None, "Plan clearance")
    assert view.operator.answer.content in ("_Plan clearance: started._", "_Plan clearance: done, 2 plans._")
    st = until(lambda: not wf.state.planning and wf.state.plans.get(planner) and wf.state, 60, "plans")
    entry = st.plans[planner]
    # the plans are in: the click's answer no longer says "started." above them
    answer_becomes(view, "_Plan clearance: done, 2 plans._")
    choose(view, planner, entry.hash)
    view.passphrase.value = PASS
    view.accept_risk.value = not entry.plan.safe or bool(entry.plan.extra.get("continues"))
    view._approve(None)
    st = until(lambda: wf.state.robot in ("done", "held", "stopped", "failed") and wf.state, 60, "run end")
    wf.wait_robot(30)
    settle(wf, view)
    return wf.state, entry


def test_after_a_run_the_plan_is_shown_executed_and_the_answers_say_how_it_ended(console):
    app, wf, view, peer = console()
    wf.capture()
    st, entry = approve_and_run(wf, view)
    n = len(entry.plan.sequence)
    assert st.robot == "done", (st.robot, st.error)
    op, sup = view.operator, view.supervisor
    # the plan panel: the executed plan and how it ended, not a plan up for review
    plans = shown(op.results.content)
    assert f"Executed: the physics plan {entry.hash} ({' → '.join(entry.plan.sequence)}): done, {n} of {n} steps" \
        in plans.replace("*", "").replace("`", ""), plans
    assert "predicted safe" not in plans and "plan hash" not in plans and "Capture and plan again" in plans
    # nor is it offered as a preview: it was planned on a shelf that is gone, and playing it would
    # draw the boxes it took out back where they stood
    assert view.preview.source("physics") == ((), None) and view.preview.frames == []
    assert view.preview.prev_info.content == \
        "_No preview: the run changed the shelf these plans were made for; capture and plan again._"
    # the 3D view says it draws the shelf as captured, which the run has changed (no look here)
    assert view.drawing.caption_node.text == "The shelf as captured before the run: capture again to see it now"
    # nothing approvable twice: the supervisor is offered nothing and told why
    assert tuple(view.approve_plan.options) == ("—",)
    assert "Pending plans" not in sup.sup_info.content and "Nothing to decide" in sup.sup_info.content
    # the answer lines: how the run ended, in place of the clicks' "started."
    assert op.answer.content == sup.answer.content == f"_Run: done, {n} of {n} steps._"
    # a click after the run is answered as itself, and the old run end does not come back over it
    op.press(None, "Plan clearance")
    assert op.answer.content.startswith("**Plan clearance: not done.**")
    settle(wf, view)
    assert op.answer.content.startswith("**Plan clearance: not done.**")
    # the next capture: the executed plan's line goes, no plans yet
    wf.capture()
    settle(wf, view)
    assert "Executed" not in op.results.content and "No plans yet" in op.results.content
    assert view.drawing.caption_node.text == "The shelf as seen"


def test_a_failed_run_and_a_held_run_say_where_they_stopped(console):
    # the robot refuses step 2: failed there, 1 step done
    app, wf, view, peer = console(script=lambda conn, step: "refuse" if step == 1 else "ok")
    wf.capture()
    st, entry = approve_and_run(wf, view)
    n, second = len(entry.plan.sequence), entry.plan.sequence[1]
    assert st.robot == "failed", (st.robot, st.error)
    words = f"failed at step 2 of {n} ({second}), 1 of {n} steps done"
    assert view.operator.answer.content == f"**Run: {words}.**"
    assert words in shown(view.operator.results.content) and "predicted safe" not in view.operator.results.content

    # the look after step 1 still sees the box taken out: held there; `continue` is the only offer
    app, wf, view, peer = console(held=True)
    wf.capture()
    st, entry = approve_and_run(wf, view)
    first = entry.plan.sequence[0]
    assert st.robot == "held", (st.robot, st.error)
    words = f"held at {first} after step 1 of {len(entry.plan.sequence)}"
    assert view.operator.answer.content == view.supervisor.answer.content == f"**Run: {words}.**"
    plans = shown(view.operator.results.content)
    assert f"Executed: the physics plan {entry.hash}" in plans.replace("*", "").replace("`", "") and words in plans
    # every box still to take was seen: the rest is offered as `continue`, the table under that line
    assert tuple(view.approve_plan.options) == ("continue",) and set(st.plans) == {"continue"}
    assert st.plans["continue"].hash in plans and "predicted safe" in plans
    assert f"offered below as “continue”, in the ids of the capture the look made (session {st.session_id})" \
        in plans
    assert entry.hash not in view.supervisor.sup_info.content.split("Pending plans")[1]
    # the 3D view draws the shelf the look saw, and on it the offered plan's first predicted frame
    assert view.drawing.base_caption == "The shelf as seen after robot step 1"
    assert view.drawing.caption_node.text.startswith("Preview of the continue plan, step 1/")


def test_the_decisions_table_names_the_planner_and_shows_outside_text_literally(console):
    from shelfpick.console.web.panels import decisions_table, executed_markdown, run_end_answer
    from shelfpick.console.workflow.state import RunEnd

    app, wf, view, peer = console()
    wf.capture()
    wf.plan("clear", wait=True)
    st = wf.state
    heur = st.plans["heuristic"]
    choose(view, "heuristic", heur.hash)
    view.who.value = MARKUP[:80]                        # names are cut at 80 characters
    view.reason.value = "b1 would fall"
    view.passphrase.value = "not the passphrase"
    view._reject(None)                                  # refused: wrong passphrase
    view.passphrase.value = PASS
    view.reason.value = MARKUP
    view._reject(None)
    settle(wf, view)
    table = view.decisions_md.content
    lines = table.splitlines()
    assert lines[0] == "| decision | planner | plan | by | at | reason |"
    rows = [[c.strip() for c in ln.split("|")[1:-1]] for ln in lines[2:]]
    assert [(r[0], r[1], r[2]) for r in rows] == [("refused", "heuristic", f"`{heur.hash}`"),
                                                  ("reject", "heuristic", f"`{heur.hash}`")]
    assert all(len(r) == 6 for r in rows)               # no outside text split a row
    assert literal(table, MARKUP) and literal(table, MARKUP[:80])
    # a hostile box id and name in a run's end are text, never markup
    end = RunEnd("physics", "abc", ("b0", MARKUP), "stopped", ("b0",), 1, MARKUP, MARKUP)
    for text in (executed_markdown(end), run_end_answer(end)):
        assert literal(text, f"stopped by {MARKUP} at step 2 of 2 ({MARKUP}), 1 of 2 steps done"), text
    row = decisions_table([{"decision": "approve", "planner": "a|b", "plan": "h", "who": "x|y", "reason": "|"}])
    assert row.splitlines()[2].count("|") == 7 and "a|b" in shown(row)     # six cells, the bars are text


def test_when_a_run_starts_the_3d_view_leaves_the_preview_for_the_shelf(console):
    """A preview played to its end drew the boxes the plan takes out as gone; when the robot started,
    the view stayed on that predicted frame until the first look came. It goes back to the shelf."""
    import dataclasses

    import numpy as np

    app, wf, view, peer = console()
    wf.capture()
    view.operator.press(None, "Plan clearance")
    until(lambda: not wf.state.planning and wf.state.plans.get("physics"), 60, "plans")
    settle(wf, view)
    view.preview.load(force=True)
    last = len(view.preview.frames) - 1
    view.preview.show_frame(last)
    gone = [b for b in wf.state.scene.ids if not view.drawing.nodes[b].box.visible]
    assert last > 0 and gone and view.drawing.caption_node.text.startswith("Preview of the physics plan")
    view.render(dataclasses.replace(wf.state, robot="running"))
    assert view.drawing.caption_node.text == "The shelf as seen"
    for b in wf.state.scene.boxes:
        assert view.drawing.nodes[b.id].box.visible
        assert np.allclose(view.drawing.nodes[b.id].box.position, b.position)


def test_while_a_session_is_replayed_the_answer_line_says_it_is_the_live_consoles(console):
    """A replay draws a stored session's plans and robot in the Operator tab, but the answer line
    stays the live console's: "Run: done, 3 of 3 steps." above a replayed session that never ran
    read as that session's end. It says whose it is, and a click made meanwhile is still answered."""
    app, wf, view, peer = console()
    wf.capture()
    replayed = wf.state.session_id                      # captured, nothing planned or run
    wf.capture()
    st, entry = approve_and_run(wf, view)
    n = len(entry.plan.sequence)
    live = f"_Run: done, {n} of {n} steps._"
    assert st.robot == "done" and view.operator.answer.content == live, (st.robot, st.error)
    until(lambda: str(replayed) in view.session_pick.options, 10, "the session listed")
    view.session_pick.value = str(replayed)
    view._replay(None)
    assert view.replay is not None and view.replay.id == replayed
    whose = f"_Live console, not the replayed session {replayed}:_ "
    assert view.operator.answer.content == whose + live
    view.operator.press(None, "Stop robot")
    assert view.operator.answer.content == whose + "_Stop robot: done._"
    view._live(None)
    assert view.operator.answer.content == "_Stop robot: done._"


def test_a_rejection_is_answered_done_not_started(console):
    """A rejection is recorded when Reject's call returns: nothing goes on after it. Its answer
    said "Reject: started." under the decisions table that already listed it."""
    app, wf, view, peer = console()
    wf.capture()
    wf.plan("clear", wait=True)
    heur = wf.state.plans["heuristic"]
    choose(view, "heuristic", heur.hash)
    view.passphrase.value = PASS
    view.reason.value = "b1 would fall"
    view._reject(None)
    assert [d["decision"] for d in wf.state.decisions] == ["reject"]
    assert view.supervisor.answer.content == "_Reject: done._"


def test_a_replayed_preview_is_captioned_as_the_replayed_sessions(console):
    """The 3D view is shared by every tab; while a replay drew a stored plan's preview its caption
    read "Preview of the physics plan, step 1/n", the words of the live preview, also on the
    Supervisor tab (live) beside the live physics plan. It names the replayed session."""
    app, wf, view, peer = console()
    wf.capture()
    wf.plan("clear", wait=True)
    settle(wf, view)
    sid = wf.state.session_id
    until(lambda: str(sid) in view.session_pick.options, 10, "the session listed")
    view.session_pick.value = str(sid)
    view._replay(None)
    assert view.drawing.caption_node.text.startswith(f"Replayed session {sid}: preview of the physics plan, step 1/")
    view.preview.follow("heuristic")              # the supervisor picks a plan: this view previews it
    assert view.drawing.caption_node.text.startswith(f"Replayed session {sid}: preview of the heuristic plan")
    view._live(None)
    assert view.drawing.caption_node.text.startswith("Preview of the heuristic plan, step 1/")


def test_a_rejected_plan_is_marked_rejected_among_the_pending_plans(console):
    """The supervisor's list of pending plans marked an approved plan but showed a rejected one like
    a plan nobody had decided on. It says who rejected it (a name is outside text)."""
    app, wf, view, peer = console()
    wf.capture()
    wf.plan("clear", wait=True)
    heur = wf.state.plans["heuristic"]
    choose(view, "heuristic", heur.hash)
    view.who.value = MARKUP[:80]
    view.passphrase.value = PASS
    view.reason.value = "b1 would fall"
    view._reject(None)
    settle(wf, view)
    pending = view.supervisor.sup_info.content.split("Deciding on")[0]
    lines = {ln.split("**")[1]: ln for ln in pending.splitlines() if ln.startswith("- **")}
    assert set(lines) == {"physics", "heuristic"}, pending
    assert "rejected" not in lines["physics"]
    assert " ❌ rejected by " in lines["heuristic"] and literal(lines["heuristic"], MARKUP[:80])


def test_button_names_in_the_supervisor_list_and_the_replay_are_quoted_not_code(console):
    """Button names the page quotes are in quotes (“Approve”), as in every other message: a few
    fixed lines wrote them in backticks, shown as code (`Approve`, `Stop robot`, `Look after step`)."""
    import re

    code_name = re.compile(r"`(Approve|Reject|Stop robot|Look after step|Accept predicted risk|Capture)`")
    app, wf, view, peer = console(held=True)
    wf.capture()
    ran = wf.state.session_id
    wf.plan("clear", wait=True)
    settle(wf, view)
    sup = view.supervisor.sup_info.content
    assert "“Approve” sends the chosen plan" in sup and not code_name.search(sup), sup
    st, _ = approve_and_run(wf, view)                   # held after step 1, with the look after it
    assert st.robot == "held", (st.robot, st.error)
    cont = st.plans["continue"]
    wf.approve(cont.hash, PASS, accept_risk=True, planner="continue")
    wf.stop("operator")                                 # withdraws it: a stop event in the look's session
    for sid, words in ((ran, "(pick one in “Look after step”)"), (st.session_id, "“Stop robot” pressed by")):
        summary = app.load_replay(sid).summary_md
        assert words in summary and not code_name.search(summary), summary


def test_session_start_times_read_as_times_not_iso_strings():
    """The Sessions table showed '2026-11-28T13:18:58.136+00:00', the store's ISO text, as it was."""
    from shelfpick.console.web.time_words import start_time_words

    assert start_time_words("2026-11-28T13:18:58.136+00:00") == "2026-11-28 13:18:58 UTC"
    assert start_time_words("2026-11-28T14:18:58.136+01:00") == "2026-11-28 14:18:58 +01:00"
    assert start_time_words(0.0) == "1970-01-01 00:00:00 UTC"
    assert start_time_words("not a time") == "not a time" and start_time_words(None) == ""


def test_decision_times_read_as_times_too():
    from shelfpick.console.web.panels import decisions_markdown

    line = shown(decisions_markdown([{"decision": "approve", "plan": "abc", "who": "sue",
                                      "at": "2026-11-28T13:18:58.136+00:00"}]))
    assert " at 2026-11-28 13:18:58 UTC" in line and "T13:18" not in line, line
