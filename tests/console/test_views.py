"""What the console shows must be the shelf (issue 33), read in a real headless Chromium.

One page session on the 6-box demo shelf (real rendering, perception, both planners over 10
sample worlds, the simulated robot, a SQLite file) walks what an operator and a supervisor do
and checks, on the page and on the scene nodes the server sent to it:

- ids on the front face of their box, and a click on an id selects that box (item 1);
- every click answered in the panel, also while a capture runs (6) and after a run (12);
- the plan table: one step a line, items whole, real planning times, the worlds explained (12);
- the preview at its real pace, a risky step shown in a world where it collapses (3);
- overlay colours are the 3D colours, ids readable in the overlay (4);
- the supervisor's `Plan` lists the plans there are, the 3D view follows it, a refusal for the
  unticked risk box keeps the passphrase (8, 9: the cell's max_plan_risk is set so low that every
  plan is predicted unsafe, so this is always checked);
- during and after the run the 3D view is the observed shelf, the robot list one row a step in
  order (2, 10); Capture afterwards shows that shelf as it now stands (7);
- replay: no live status, Capture and Plan disabled, the newest session first, its images,
  an HTML export from the page (14).

Two light tests without a console: the exported HTML names the approved plan when two planners
gave one sequence (13), and a collapse names perceived ids only (11).
"""
from __future__ import annotations

import re
import threading
import time

import numpy as np
import pytest

from test_browser import (PASS, WATCHED, browser, canvas_box, hover_until_clickable, mark,  # noqa: F401
                          open_page, press, tick, until, wait_text)

pytestmark = pytest.mark.browser

STRICT = 1e-4     # the cell's max_plan_risk in the page session (the lowest a cell file may set)


class GatedDemo:
    """The 6-box demo shelf; a capture waits while the gate is shut (a camera that is slow)."""

    def __init__(self) -> None:
        from shelfpick.console.sources import DEMO_DIR, DemoSource

        self.demo = DemoSource.from_dir(DEMO_DIR, "demo-small-6", seed=0)
        self.name = "demo"
        self.gate = threading.Event()
        self.gate.set()

    def capture(self):
        assert self.gate.wait(60), "the test never opened the gate"
        return self.demo.capture()

    def look_again(self, world, step, attempt=0):
        return self.demo.look_again(world, step, attempt)


@pytest.fixture
def demo_console(tmp_path):
    from shelfpick.console.web.app import ConsoleApp
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    from shelfpick.planning.priors import CellPriors

    store = SessionStore(tmp_path / "views.sqlite")
    source = GatedDemo()
    # a cell that accepts next to no risk: every plan is predicted unsafe, so the refusal for an
    # unticked risk box (item 9) is always checked, not only when the risk gate happens to refuse
    wf = Workflow(source, store, lambda truth, seed: open_robot("sim?delay=0.4", truth=truth, seed=seed), PASS,
                  samples=10, seed=0, priors=CellPriors(max_plan_risk=STRICT))
    app = ConsoleApp(wf, port=0)
    WATCHED.append(wf)
    yield app, wf, store, source
    WATCHED.remove(wf)
    app.stop()
    store.close()


def text(page) -> str:
    page.bring_to_front()
    return page.evaluate("document.body.innerText")


def settle(wf, timeout: float = 15.0) -> None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = wf.state.version
        time.sleep(0.4)
        if wf.state.version == v:
            return


def project(view, page, point) -> tuple[float, float]:
    """Where a shelf-frame point shows on this browser's canvas (its camera, as it reports it)."""
    cam = view.client.camera
    cb = canvas_box(page)
    p, look, up = (np.asarray(v, dtype=float) for v in (cam.position, cam.look_at, cam.up_direction))
    f = (look - p) / np.linalg.norm(look - p)
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    d = np.asarray(point, dtype=float) - p
    t = np.tan(cam.fov / 2.0)
    nx = d @ r / ((d @ f) * t * cb["width"] / cb["height"])
    ny = d @ u / ((d @ f) * t)
    assert abs(nx) < 0.9 and abs(ny) < 0.9, f"{point} is off screen"
    return cb["x"] + (1 + nx) * cb["width"] / 2, cb["y"] + (1 - ny) * cb["height"] / 2


def label_in_shelf_frame(box, label_pos) -> np.ndarray:
    from shelfpick.perception.scene import quat_to_matrix

    return np.asarray(box.position) + np.asarray(quat_to_matrix(box.orientation)) @ np.asarray(label_pos)


def check_labels_and_click_one(page, view, wf) -> str:
    """Item 1: every id sits inside its box's front face; a click on the id of a box with another box
    on it selects that box, not the one above."""
    scene = wf.state.scene
    for b in scene.boxes:
        pos = np.asarray(view.nodes[b.id].label.position, dtype=float)
        assert abs(pos[1] + b.size[1] / 2) < 0.01, f"{b.id}: label not on the front face ({pos})"
        assert abs(pos[0]) < b.size[0] / 2 and abs(pos[2]) < b.size[2] / 2, f"{b.id}: label outside the face"
    under = [b for b in scene.boxes if any(o.position[2] > b.position[2] + b.size[2] / 2 - 0.02
                                           and abs(o.position[0] - b.position[0]) < 0.08 for o in scene.boxes)]
    assert under, "the demo shelf has a box with another on it"
    box = under[0]
    if wf.state.target == box.id:
        wf.select_target(next(i for i in scene.ids if i != box.id))
        until(lambda: view.target.value == wf.state.target, 10, "dropdown in step")
    x, y = project(view, page, label_in_shelf_frame(box, view.nodes[box.id].label.position))
    hover_until_clickable(page, x, y)
    page.mouse.down()
    page.mouse.up()
    until(lambda: wf.state.target == box.id, 15, f"the click on the label {box.id} to select {box.id} "
          f"(selected: {wf.state.target})")
    return box.id


def check_overlay(view, wf) -> None:
    """Item 4: each box's 3D colour is the colour of its outline in the overlay the page shows;
    its id is written at least 3 % of the image width tall."""
    img = np.asarray(view.operator.img_overlay.image)
    w = img.shape[1]
    for b in wf.state.scene.boxes:
        col = np.asarray(view.nodes[b.id].box.color, dtype=int)
        hit = np.all(img.astype(int) == col, axis=-1)
        assert hit.sum() > 30, f"{b.id}: its 3D colour {tuple(col)} is not its overlay outline's"
        ys, xs = np.nonzero(hit)
        sub = img[ys.min():ys.max() + 1, xs.min():xs.max() + 1]
        white = np.nonzero(np.all(sub >= 250, axis=-1))[0]
        assert white.size and white.max() - white.min() >= 0.03 * w, f"{b.id}: id text too small"


def cells(page, row: str) -> list[str]:
    """The cells of the plan table's row `row` (as the page shows them)."""
    return page.evaluate("""name => {
        for (const tr of document.querySelectorAll("tr")) {
            const tds = [...tr.children].map(c => c.innerText);
            if (tds.length && tds[0].trim() === name) return tds.slice(1);
        }
        return null;
    }""", row)


def check_plan_table(page, st) -> None:
    """Item 12: steps one a line with box and risk together, real planning times, worlds explained."""
    risks = cells(page, "collapse risk per step")
    assert risks is not None, "no risk row"
    for col, e in zip(risks, [st.plans[p] for p in ("physics", "heuristic") if p in st.plans]):
        lines = [ln for ln in col.split("\n") if ln.strip()]
        assert len(lines) == len(e.plan.sequence), col
        for i, (ln, p) in enumerate(zip(lines, e.plan.predicted)):
            assert ln.strip() == f"{i + 1}.\u00a0{p.box}\u00a0{100 * p.collapse_prob:.0f}%", ln
    times = cells(page, "planning time")
    assert times and all(float(t.split("\u00a0")[0]) > 0.0 for t in times), times
    worlds = cells(page, "sample worlds behind the risks")
    # searched, or asked after the search's (the baseline's: after the worlds its steps were first predicted in)
    assert worlds and all("search" in w or "first predicted" in w for w in worlds), worlds
    assert "sample worlds: shelves the camera cannot tell apart" in text(page)


def check_preview(page, view, st) -> None:
    """Item 3: a risky step plays in a world where it collapses ("... in 1 world of 10"), the
    collapsing box moves on the scene nodes; playing follows the recorded time."""
    name, entry = next(((n, e) for n, e in st.plans.items() if any(
        c.get("result") is not None for c in e.collapse_steps.values())), (None, None))
    assert name is not None, "the demo shelf's plans have a risky step"
    k, shown = next((k, c) for k, c in sorted(entry.collapse_steps.items()) if c.get("result") is not None)
    view.preview.prev_plan.value = name           # the operator picks that plan in `Preview plan`
    until(lambda: view.preview.frames and view.preview.frames[0].world, 10, "preview loaded")
    idx = [i for i, f in enumerate(view.preview.frames) if f.step == k]
    view.slider.value = idx[0]
    n = shown["collapsed_in"]
    wait_text(page, f"collapses in {n} world{'s' if n != 1 else ''} of {shown['of']}: shown in world")
    fell = view.preview.frames[idx[-1]].collapsed[0]
    node = view.nodes[fell].box
    before = (np.asarray(node.position, dtype=float).copy(), np.asarray(node.wxyz, dtype=float).copy())
    moved = turned = 0.0
    for i in idx:                         # scrub through the step: the box's node moves as it falls
        view.slider.value = i
        if not node.visible:
            moved = np.inf
            break
        moved = max(moved, float(np.linalg.norm(np.asarray(node.position, dtype=float) - before[0])))
        dot = abs(float(np.dot(np.asarray(node.wxyz, dtype=float), before[1])))
        turned = max(turned, float(np.degrees(2 * np.arccos(min(1.0, dot)))))
    wait_text(page, f"collapsed: {fell}")
    assert moved > 0.01 or turned > 5, f"{fell} moved {moved:.3f} m, turned {turned:.1f}° at most"
    # real pace: the time the page shows advances with the wall clock
    view.slider.value = 0
    press(page, "Play")
    t_page = []
    end = time.monotonic() + 8.0
    while time.monotonic() < end and view.preview.playing or not t_page:
        m = re.search(r"t = ([0-9.]+) s", text(page))
        if m:
            t_page.append((time.monotonic(), float(m.group(1))))
        time.sleep(0.25)
        if time.monotonic() > end + 5:
            break
    span = [(w, t) for w, t in t_page if t > 0]
    assert len(span) >= 3, t_page
    (w0, s0), (w1, s1) = span[0], span[-1]
    assert 0.6 < (s1 - s0) / (w1 - w0) < 1.4, f"preview pace {(s1 - s0) / (w1 - w0):.2f} x real time"
    press(page, "Pause")


def test_the_page_shows_the_shelf_from_capture_to_replay(browser, demo_console, tmp_path):
    app, wf, store, source = demo_console
    ctx = browser.new_context(viewport={"width": 1400, "height": 900}, accept_downloads=True)
    try:
        page, view = open_page(ctx, app)
        # item 6: a click while the camera is still busy is answered, and the answer stays
        source.gate.clear()
        cap = threading.Thread(target=wf.capture, daemon=True)
        cap.start()
        until(lambda: wf.state.capturing, 10, "capturing")
        press(page, "Plan clearance")
        wait_text(page, "Plan clearance: not done.")
        source.gate.set()
        cap.join(60)
        until(lambda: wf.state.scene is not None and not wf.state.capturing, 60, "capture")
        settle(wf)
        wait_text(page, "captured demo:demo-small-6")
        assert "Plan clearance: not done." in text(page)
        mark("capture answered")

        target = check_labels_and_click_one(page, view, wf)
        check_overlay(view, wf)
        mark("labels, overlay")

        press(page, "Plan extraction")
        until(lambda: not wf.state.planning and wf.state.plans, 120, "plans")
        st = wf.wait_planning(60)          # and the worlds its risky steps are shown in, just after
        assert st.plans["physics"].plan.sequence[-1] == target
        wait_text(page, "est. execution")
        check_plan_table(page, st)
        check_preview(page, view, st)
        mark("plans, preview")

        # the supervisor: the plans there are, the 3D view follows the choice, the passphrase stays
        # when only the risk box was not ticked
        press(page, "Supervisor", role="tab")
        assert tuple(view.supervisor.approve_plan.options) == ("physics", "heuristic")
        risky = max(st.plans.values(), key=lambda e: e.plan.risk)
        cur = view.supervisor.approve_plan.value
        picks = [n for n in ("physics", "heuristic") if n != cur] + [cur]
        if picks[-1] != risky.plan.planner:
            picks.append(risky.plan.planner)
        for choice in picks:                                         # as the supervisor picks them
            view.supervisor.approve_plan.value = choice
            until(lambda: view.preview.prev_plan.value == choice, 10,
                  f"3D view follows the choice {choice} (shows {view.preview.prev_plan.value})")
        fill = page.locator('xpath=//label[text()="Passphrase"]/ancestor::div[contains(@class,"mantine-Flex-root")]'
                            '[1]//input')
        assert not risky.plan.safe, f"risk {risky.plan.risk} is safe under max_plan_risk {STRICT}"
        fill.fill(PASS)
        fill.evaluate("e => e.blur()")
        until(lambda: view.passphrase.value == PASS, 10, "passphrase typed")
        assert not view.accept_risk.value
        press(page, "Approve")
        wait_text(page, "Approve: not done.")
        wait_text(page, "Accept predicted risk")
        assert view.passphrase.value == PASS and fill.input_value() == PASS
        assert wf.state.approved is None and wf.state.robot == "idle"
        # the run: the physics plan (the heuristic one empties the shelf: nothing left to capture)
        run = st.plans["physics"]
        def review(choice: str) -> None:
            """Another plan under review: the 3D view follows it, the passphrase is cleared (h2's rule),
            then typed again."""
            view.supervisor.approve_plan.value = choice
            until(lambda: view.preview.prev_plan.value == choice, 10, "3D view follows the choice")
            until(lambda: view.passphrase.value == "" and fill.input_value() == "", 10, "passphrase cleared")
            fill.fill(PASS)
            fill.evaluate("e => e.blur()")
            until(lambda: view.passphrase.value == PASS, 10, "passphrase typed")

        if view.supervisor.approve_plan.value == "physics":   # the riskier plan was physics: the other first
            review("heuristic")
        review("physics")
        if not run.plan.safe:
            tick(page, "Accept predicted risk")
            until(lambda: view.accept_risk.value, 10, "risk accepted")
        before = wf.state.run_end
        press(page, "Approve")
        # answered: "Approve: started.", or already how the run ended (the answer line says it then)
        until(lambda: "Approve: started." in text(page) or (
            wf.state.run_end not in (None, before) and "Run: " in text(page)), 30, "the approval answered")
        mark("approved")

        # item 2: after the first step the 3D view is the shelf the look saw (the box is gone)
        first = run.plan.sequence[0]
        until(lambda: wf.state.verifications, 60, "the first look")
        until(lambda: first not in view.nodes, 20, f"{first} gone from the 3D view after step 1")
        st = until(lambda: wf.state.robot in ("done", "failed", "stopped", "held") and wf.state, 120, "run end")
        settle(wf)
        done = list(st.outcome.completed) if st.outcome is not None else []
        assert done, (st.robot, st.error)
        if st.robot != "held":
            assert not set(done) & set(view.nodes), (done, sorted(view.nodes))
            assert len(view.nodes) == len(st.observed.boxes)
        # item 10: one row a step, in step order, each with the robot's answer then its look
        press(page, "Operator", role="tab")
        shown = text(page)
        at = [shown.index(f"{i + 1}\t{b}\tack → done\t") for i, b in enumerate(done)]
        assert at == sorted(at), at
        for v in st.verifications:
            row = shown[shown.index(f"{v.step + 1}\t{v.box}\t"):].split("\n")[0]
            assert ("✓" if v.within else "⚠") in row, row
        mark("run shown")

        # item 12 / 6: after the run the plan buttons answer, in words, without backticks
        press(page, "Plan clearance")
        wait_text(page, "Plan clearance: not done.")
        assert "`" not in text(page)

        # item 7: Capture shows the shelf the robot worked on, as it now stands
        press(page, "Capture")
        until(lambda: wf.state.session_id is not None and wf.state.session_id > st.session_id
              and not wf.state.capturing, 60, "capture after the run")
        wait_text(page, "as the robot left it")
        left = len(wf.state.truth.boxes)
        assert left == 6 - len(done), (left, done)
        until(lambda: len(view.nodes) == len(wf.state.scene.boxes), 10, "the new shelf drawn")
        mark("captured again")

        # item 14: replay shows the stored session only; nothing live can be pressed meanwhile
        press(page, "Sessions", role="tab")
        newest = str(wf.state.session_id)
        until(lambda: view.session_pick.value == newest, 10, "newest session first")
        view.session_pick.value = str(st.session_id)        # the operator picks the run's session
        press(page, "Replay")
        wait_text(page, f"Session {st.session_id}")
        assert view.sessions.img_rgb.image.shape == wf.state.capture.rgb.shape      # the session's images
        assert page.locator("img").count() >= 2
        press(page, "Operator", role="tab")
        wait_text(page, f"Replaying session {st.session_id}")
        shown = text(page)
        assert "Source demo" not in shown and "as the robot left it" not in shown, shown[:600]
        for name in ("Capture", "Plan extraction", "Plan clearance"):
            assert page.get_by_role("button", name=name, exact=True).is_disabled(), name
        press(page, "Sessions", role="tab")
        with page.expect_download(timeout=30_000) as dl:
            press(page, "Export HTML")
        out = tmp_path / "export.html"
        dl.value.save_as(out)
        assert f"shelfpick session {st.session_id}" in out.read_text(encoding="utf-8")
        press(page, "Back to live")
        press(page, "Operator", role="tab")
        until(lambda: not page.get_by_role("button", name="Capture", exact=True).is_disabled(), 10, "live again")
        mark("replayed, exported")
    finally:
        ctx.close()


def test_the_export_marks_the_approved_plan_when_two_planners_agree(browser, tmp_path):
    """Item 13: physics and heuristic gave one sequence (one hash); the heuristic plan was approved
    and ran: the exported page marks that card only and the decision names it."""
    from shelfpick.console.web.replay import render_html
    from shelfpick.console.web.replay_view import record_view
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.perception.render import default_camera, render
    from shelfpick.perception.scene import Box, Scene, Shelf
    from shelfpick.planning.plan import Plan, StepPrediction

    scene = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)),), default_camera())
    store = SessionStore(tmp_path / "s.sqlite")
    try:
        sid = store.new_session("test", render(scene, seed=0, noise=False), scene, scene, None, {})
        plans = [Plan("extract", "b0", p, ("b0",), (StepPrediction("b0", 0.0),), True, {}, 0)
                 for p in ("physics", "heuristic")]
        h = {store.add_plan(sid, p) for p in plans}
        assert len(h) == 1
        h = h.pop()
        store.add_decision(sid, h, "approve", "sue")
        store.set_outcome(sid, {"plan": h, "planner": "heuristic", "sequence": ["b0"], "completed": ["b0"],
                                "ok": True, "steps": [{"step": 0, "box": "b0", "status": "done"}]})
        rec = store.load_session(sid)
    finally:
        store.close()
    assert "(the **heuristic** plan)" in record_view(rec).summary_md
    page = browser.new_page()
    try:
        page.set_content(render_html(rec))
        marked = page.evaluate("""() => [...document.querySelectorAll(".card")]
            .filter(c => c.querySelector(".ok")).map(c => c.querySelector("h3").innerText)""")
        assert marked == ["heuristic plan approved"], marked
    finally:
        page.close()


def test_the_export_marks_a_rejected_plan_and_who_rejected_it(tmp_path):
    """The exported page marked the approved card only: a plan the supervisor turned down looked
    like one nobody had looked at. The rejecter's name is outside text: escaped."""
    from shelfpick.console.web.replay import render_html
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.perception.render import default_camera, render
    from shelfpick.perception.scene import Box, Scene, Shelf
    from shelfpick.planning.plan import Plan, StepPrediction

    scene = Scene(Shelf(), (Box("b0", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)),
                            Box("b1", (0.2, 0.2, 0.2), (0.3, 0.1, 0.1))), default_camera())
    store = SessionStore(tmp_path / "s.sqlite")
    try:
        sid = store.new_session("test", render(scene, seed=0, noise=False), scene, scene, None, {})
        gate = {"search": {"plan_risk": {"probability": 0.0093, "low": 0.0086, "high": 0.028, "failed_worlds": 1,
                                         "worlds": 10, "max_plan_risk": 0.05}}}
        phys = store.add_plan(sid, Plan("clear", None, "physics", ("b0", "b1"),
                                        (StepPrediction("b0", 0.0), StepPrediction("b1", 0.1)), True, {}, 0, gate))
        heur = store.add_plan(sid, Plan("clear", None, "heuristic", ("b1", "b0"),
                                        (StepPrediction("b1", 0.2), StepPrediction("b0", 0.0)), False, {}, 0))
        store.add_decision(sid, heur, "reject", "<b>sue</b>", "b1 would fall")
        store.add_decision(sid, phys, "approve", "ann")
        page = render_html(store.load_session(sid))
    finally:
        store.close()
    cards = page.split('<div class="card">')[1:]
    (h_card,) = [c for c in cards if c.startswith("<h3>heuristic plan")]
    (p_card,) = [c for c in cards if c.startswith("<h3>physics plan")]
    assert 'rejected by &lt;b&gt;sue&lt;/b&gt;</span>' in h_card.split("</h3>")[0]
    assert "rejected" not in p_card.split("</h3>")[0] and "approved" in p_card.split("</h3>")[0]
    # the risk in the console's words: the calibrated chance, and the worst step's share apart
    assert "chance of a collapse 0.9%, up to 2.8%; worst step collapses or collides in 10% of sample worlds" in p_card
    assert "worst step collapses or collides in 20% of sample worlds" in h_card and "chance of" not in h_card
    # the decisions table says when as the console does, not the store's ISO text
    assert "<th>when</th>" in page and not re.search(r"\d{4}-\d\d-\d\dT\d\d:", page)   # nowhere, header too
    assert re.search(r"<td>\d{4}-\d\d-\d\d \d\d:\d\d:\d\d UTC</td><td>&lt;b&gt;sue", page)


def test_a_collapse_names_the_boxes_the_operator_knows():
    """Item 11: perceived ids, and a box the camera never saw said in words, not the simulator's id."""
    from shelfpick.console.web.replay_view import _actual_text
    from shelfpick.console.robot.drivers import seen_names

    assert seen_names(["b2", None]) == "b2, a box the camera did not see"
    assert seen_names([None, None]) == "2 boxes the camera did not see"
    step = {"status": "done", "detail": {"collapsed_ids": ["b2", "b9"]}}
    assert _actual_text(step, {"b1", "b2"}) == "collapsed: b2, a box the camera did not see"
