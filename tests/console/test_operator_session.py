"""A whole operator session in headless Chromium, scripted, with a screenshot of every stage.

The shelf is the generated `lean` shelf of tests/console/test_closed_loop.py (seed 23): a long box
leans on a column and perception reports it upright. The robot is the simulated one (its world a
seeded draw of what the camera cannot know); the demo camera renders that world after each
step, and the heuristic clearance is held after its third step, the rest offered as `continue`.

Capture, a target picked in the 3D view, both plans (extraction, then clearance), the preview,
the supervisor approves the heuristic clearance, the console holds the robot after step 1,
the supervisor approves `continue` (offered when every box still to take was seen; else the
operator plans again from the look that held it), a new capture and plan, Stop during the run, replay of the
held session and its HTML export from the page. Each stage is checked on the page and saved as a
PNG in a temporary folder; SHELFPICK_SHOTS=DIR saves them there as well (how the README's and
docs/console.md's pictures are made: static/readme/make_screenshots.py).
"""
from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest

from test_browser import (PASS, WATCHED, browser, click_box_in_3d, fill_text, mark, open_page,  # noqa: F401
                          press, tick, until, wait_text)

pytestmark = pytest.mark.browser


@pytest.fixture
def lean_app(tmp_path):
    from shelfpick.console.web.app import ConsoleApp
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.sources import DemoSource
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow
    from shelfpick.perception.render import default_camera
    from shelfpick.planning.shelves import generate

    truth = generate("lean", SEED, 8)
    truth = type(truth)(truth.shelf, truth.boxes, default_camera())
    store = SessionStore(tmp_path / "operator.sqlite")
    delay = [0.0]                      # seconds per robot step: slow steps let Stop land mid-run
    wf = Workflow(DemoSource([("lean", truth)], seed=2), store,
                  lambda t, seed: open_robot(f"sim?delay={delay[0]}", truth=t, seed=seed), PASS, samples=2)
    app = ConsoleApp(wf, port=0)
    WATCHED.append(wf)
    yield app, wf, store, delay
    WATCHED.remove(wf)
    app.stop()
    store.close()


SEED = 23   # lean seeds 2, 6, 8, 23 tried with the simulated robot: 23 holds (after step 3) and offers continue


class Shots:
    """Screenshots of the stages, numbered, in `folder` (and SHELFPICK_SHOTS when set)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        folder.mkdir(parents=True, exist_ok=True)
        self.extra = Path(os.environ["SHELFPICK_SHOTS"]) if os.environ.get("SHELFPICK_SHOTS") else None
        self.n = 0

    def take(self, page, name: str) -> Path:
        self.n += 1
        page.bring_to_front()
        time.sleep(0.8)                     # the 3D view draws what the server sent at its next frames
        page.evaluate("""() => {            // viser's note that this browser has no GPU: not the console's
            for (const el of document.querySelectorAll("div")) {
                if (!el.innerText || !el.innerText.startsWith("Software WebGL rendering detected")) continue;
                const b = el.querySelector("button");
                if (b) { b.click(); return; }
            }
        }""")
        time.sleep(0.4)
        out = self.folder / f"{self.n:02d}-{name}.png"
        page.screenshot(path=str(out))
        assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and out.stat().st_size > 20_000, out
        if self.extra is not None:
            self.extra.mkdir(parents=True, exist_ok=True)
            shutil.copy(out, self.extra / out.name)
        mark(f"shot {out.name}")
        return out


def page_text(page) -> str:
    page.bring_to_front()
    return page.evaluate("document.body.innerText")


def approve(page, view, planner: str, risk: bool) -> None:
    """The supervisor picks `planner`, types the passphrase, ticks the risk box if asked, approves."""
    press(page, "Supervisor", role="tab")
    until(lambda: planner in view.supervisor.approve_plan.options, 10, f"{planner} offered")
    view.supervisor.approve_plan.value = planner
    fill_text(page, "Passphrase", PASS)
    until(lambda: view.passphrase.value == PASS, 10, "passphrase typed")
    if risk:
        tick(page, "Accept predicted risk")
        until(lambda: view.accept_risk.value, 10, "risk accepted")
    before = view.wf.state.run_end
    press(page, "Approve")
    # answered: "Approve: started.", or already how the run ended (the answer line says it then)
    until(lambda: "Approve: started." in page_text(page) or (
        view.wf.state.run_end not in (None, before) and "Run: " in page_text(page)), 30, "the approval answered")


def test_an_operator_session_from_capture_to_html_export(browser, lean_app, tmp_path):
    app, wf, store, delay = lean_app
    shots = Shots(tmp_path / "shots")
    ctx = browser.new_context(viewport={"width": 1400, "height": 900}, accept_downloads=True)
    try:
        page, view = open_page(ctx, app)
        press(page, "Capture")
        st = until(lambda: wf.state.scene is not None and not wf.state.capturing and wf.state, 60, "capture")
        assert st.scene.boxes, st.error
        wait_text(page, "Capture: done.")
        shots.take(page, "captured")

        # a target picked in the 3D view: the lowest box of the left half
        box = min((b for b in st.scene.boxes if b.position[0] < 0), key=lambda b: b.position[2])
        if st.target == box.id:
            wf.select_target(next(i for i in st.scene.ids if i != box.id))
            until(lambda: view.target.value == wf.state.target, 10, "dropdown in step")
        click_box_in_3d(page, view, box)
        until(lambda: wf.state.target == box.id, 15, "target picked in 3D")
        press(page, "Plan extraction")
        until(lambda: not wf.state.planning and wf.state.plans, 120, "extraction plans")
        wait_text(page, "est. execution")
        shots.take(page, "plans-extraction")

        press(page, "Plan clearance")
        st = until(lambda: not wf.state.planning and wf.state.plans and wf.state.task == "clear" and wf.state,
                   120, "clearance plans")
        heur = st.plans["heuristic"]
        view.preview.prev_plan.value = "heuristic"
        press(page, "Play")
        until(lambda: int(view.slider.value) > 3, 20, "preview playing")
        shots.take(page, "preview")
        press(page, "Pause")

        # the heuristic clearance, approved: a look after a step holds the robot
        approve(page, view, "heuristic", risk=True)
        st = until(lambda: wf.state.robot not in ("idle", "running", "stopping") and wf.state, 120, "held")
        assert st.robot == "held", (st.robot, st.error)
        press(page, "Operator", role="tab")
        wait_text(page, "Robot held before step")
        shown = page_text(page)
        assert "|---" not in shown and "| |" not in shown, "raw markdown in the plans panel"
        offered = tuple(view.supervisor.approve_plan.options)
        assert offered == (("continue",) if "continue" in st.plans else ("—",)), offered
        if "continue" in st.plans:
            assert "continue" in shown.split("Robot held")[0], "the continue plan is not in the plans table"
        shots.take(page, "held")

        # the supervisor continues the held plan (when every box still to take was seen), else the
        # operator plans again from the look that held it; the hold notice goes once that runs
        if "continue" in st.plans:
            nxt = st.plans["continue"]
            # the tick forgotten: refused before the passphrase is used, so it stays typed (item 9)
            press(page, "Supervisor", role="tab")
            view.supervisor.approve_plan.value = "continue"
            fill_text(page, "Passphrase", PASS)
            until(lambda: view.passphrase.value == PASS, 10, "passphrase typed")
            press(page, "Approve")
            wait_text(page, "Approve: not done.")
            assert view.passphrase.value == PASS and wf.state.approved is None
            approve(page, view, "continue", risk=True)
        else:
            press(page, "Plan clearance")
            nxt = until(lambda: not wf.state.planning and wf.state.plans.get("physics"), 120, "plans from the look")
            approve(page, view, "physics", risk=not nxt.plan.safe)
        st = until(lambda: wf.state.outcome is not None and wf.state.outcome.plan == nxt.hash
                   and wf.state.robot in ("done", "failed", "stopped", "held") and wf.state, 120, "the next run")
        press(page, "Operator", role="tab")
        wait_text(page, "Outcome:")
        shown = page_text(page)
        assert "|---" not in shown
        if st.robot != "held":
            assert "Robot held before step" not in shown
            assert "continue" not in view.supervisor.approve_plan.options
        shots.take(page, "after-hold")

        # a new capture and plan; Stop while the robot runs
        press(page, "Capture")
        until(lambda: wf.state.session_id is not None and not wf.state.capturing
              and wf.state.robot == "idle" and wf.state.scene is not None, 60, "capture after the run")
        if wf.state.scene.boxes:
            delay[0] = 3.0                          # slow steps: Stop lands in the middle of the run
            press(page, "Plan clearance")
            st = until(lambda: not wf.state.planning and wf.state.plans and wf.state, 120, "plans")
            phys = st.plans["physics"]
            approve(page, view, "physics", risk=not phys.plan.safe)
            until(lambda: wf.state.robot == "running", 30, "running")
            press(page, "Operator", role="tab")
            press(page, "Stop robot")
            st = until(lambda: wf.state.robot in ("stopped", "done", "failed", "held") and wf.state, 60, "stopped")
            assert st.robot == "stopped", (st.robot, st.error)
            wait_text(page, "Run: stopped by operator")     # the answer line: how the run ended
            wait_text(page, "Robot: stopped")
            shots.take(page, "stopped")
        held = [r for r in store.list_sessions() if r.get("status") == "held"]
        assert held, store.list_sessions()

        # replay of the held session and its HTML export
        press(page, "Sessions", role="tab")
        view.session_pick.value = str(held[0]["id"])
        press(page, "Replay")
        wait_text(page, f"Session {held[0]['id']}")
        shots.take(page, "replay")
        with page.expect_download(timeout=30_000) as dl:
            press(page, "Export HTML")
        out = tmp_path / "session.html"
        dl.value.save_as(out)
        export = ctx.new_page()
        export.goto(out.as_uri())
        export.get_by_text(f"shelfpick session {held[0]['id']}").first.wait_for(timeout=10_000)
        shots.take(export, "html-export")
        export.close()
        press(page, "Back to live")
        until(lambda: view.replay is None, 15, "back to live")
        with view.lock:                  # the live shelf drawn before the browser closes: closing it
            pass                         # mid-draw left viser messages queued on a closed connection
        assert shots.n == 8
    finally:
        ctx.close()
