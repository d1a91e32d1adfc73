"""Regenerate the README screenshots of the operator console (headless Chromium).

    .venv/bin/python static/readme/make_screenshots.py

operator.png: the real pipeline on the built-in demo shelf (render -> perception ->
both planners -> 3D view, plans side by side).

collapse-preview.png: the preview of the heuristic plan on a shelf with a leaning
box, predicted by the real Predictor on that scene given directly (the current
perception does not report leaning boxes, so this one skips the camera): pulling
the tall box first drops the box leaning on it, which the preview shows falling
and marks in red.
"""
from __future__ import annotations

import math
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT))
OUT = Path(__file__).resolve().parent
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]


def lean_scene():
    from perception.render import default_camera
    from perception.scene import Box, Scene, Shelf

    a = math.radians(20)
    return Scene(Shelf(), (
        Box("b0", (0.2, 0.2, 0.2), (-0.38, 0.1, 0.1)),
        Box("b1", (0.12, 0.25, 0.40), (-0.1098, 0.13, 0.2085), (math.cos(a / 2), 0, math.sin(a / 2), 0)),
        Box("b2", (0.17, 0.17, 0.5), (0.1, 0.1, 0.25)),
        Box("b3", (0.2, 0.2, 0.2), (0.35, 0.1, 0.1)),
    ), default_camera())


def open_view(browser, app):
    page = browser.new_page(viewport={"width": 1280, "height": 760})
    page.goto(app.url)
    page.get_by_role("button", name="Capture").wait_for(timeout=60_000)
    while not app.views:
        time.sleep(0.1)
    time.sleep(1.0)
    for btn in page.locator(".mantine-Notification-closeButton").all():
        btn.click(force=True)
    return page, next(iter(app.views.values()))


def aim(view, position, look_at):
    cam = view.client.camera
    cam.up_direction = (0.0, 0.0, 1.0)
    cam.position = position
    cam.look_at = look_at


def main() -> int:
    from playwright.sync_api import sync_playwright

    from console.app import ConsoleApp
    from console.robot import open_robot
    from console.sources import DemoSource, builtin_scene
    from console.store import SessionStore
    from console.workflow import PlanEntry, Workflow
    from perception.pipeline import perceive
    from perception.render import render
    from planning.planner import make_plan
    from planning.predict import Predictor

    with sync_playwright() as p, tempfile.TemporaryDirectory() as tmp:
        browser = p.chromium.launch(executable_path="/usr/bin/chromium", args=ARGS)

        # 1. operator view: the real pipeline on the built-in demo shelf
        store = SessionStore(Path(tmp) / "s.sqlite")
        wf = Workflow(DemoSource([("builtin", builtin_scene())], seed=0), store,
                      lambda truth, seed: open_robot("sim", truth=truth, seed=seed), "pw", samples=4)
        app = ConsoleApp(wf, port=0)
        page, view = open_view(browser, app)
        st = wf.capture()
        wf.select_target(min(st.scene.boxes, key=lambda b: b.position[2] - b.position[0]).id)
        wf.plan("extract", wait=True)
        aim(view, (0.55, -1.75, 1.0), (0.0, 0.15, 0.3))
        time.sleep(2.0)
        page.screenshot(path=str(OUT / "operator.png"))
        app.stop()
        store.close()
        print("operator.png:", wf.state.message, wf.state.error or "")

        # 2. collapse preview: the heuristic plan on a shelf with a leaning box
        scene = lean_scene()
        cap = render(scene, seed=0)
        wf = Workflow(None, None, None, "pw", samples=4)
        app = ConsoleApp(wf, port=0)
        page, view = open_view(browser, app)
        pred = Predictor(scene, samples=4, seed=0)
        plans = {}
        for planner in ("physics", "heuristic"):
            plan = make_plan(scene, "extract", "b2", planner, 4, 0, predictor=pred)
            plans[planner] = PlanEntry(plan, plan.content_hash(), tuple(pred.preview(plan.sequence, 0)))
        pred.close()
        wf._set(source="lean shelf (scene given directly)", capture=cap, overlay=perceive(cap).overlay,
                scene=scene, truth=scene, target="b2", task="extract", plans=plans,
                message="preview of the heuristic plan: pulling b2 first drops b1")
        time.sleep(1.0)
        view.prev_plan.value = "heuristic"
        frames = view.frames
        hit = [i for i, k in enumerate(frames) if k.collapsed]
        view.slider.value = hit[len(hit) * 2 // 3] if hit else len(frames) - 1
        aim(view, (0.5, -1.5, 0.75), (0.0, 0.15, 0.25))
        time.sleep(2.0)
        page.screenshot(path=str(OUT / "collapse-preview.png"))
        print("collapse-preview.png:", {k: (e.plan.sequence, round(e.plan.risk, 2)) for k, e in plans.items()})
        app.stop()
        browser.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
