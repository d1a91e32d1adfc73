"""Markup from outside arrives as literal text in a real browser (Debian's headless Chromium):
no element is created, no script runs, no URL from the text is fetched, and other viewers see the
same characters. Marker `browser` (runs by default, like tests/console/test_browser.py)."""
from __future__ import annotations

from pathlib import Path

import pytest

from safety_kit import fault

pytestmark = pytest.mark.browser
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
EVIL = ('<iframe id="pwn1" src="javascript:parent.__pwned=1"></iframe><img id="pwn2" src="http://evil.example/x.png" '
        'onerror="window.__pwned=2"> ![p](http://evil.example/y.png) [c](http://evil.example/) **B**')


def test_markup_in_robot_text_names_and_notes_is_literal_in_two_browsers(tmp_path):
    from playwright.sync_api import sync_playwright

    from shelfpick.console.web.app import ConsoleApp
    from shelfpick.console.robot.drivers import RobotEvent, RobotOutcome
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing (make test installs it)")
    store = SessionStore(tmp_path / "b.sqlite")
    wf = Workflow(None, store, lambda t, s: None, "pw")
    app = ConsoleApp(wf, port=0)
    fetched: list[str] = []
    try:
        with sync_playwright() as p:
            b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
            pages = []
            for _ in range(2):                           # the operator and an observer
                ctx = b.new_context()
                ctx.route("**/*", lambda route: (fetched.append(route.request.url), route.abort())
                          if "evil.example" in route.request.url else route.continue_())
                page = ctx.new_page()
                page.goto(app.url)
                page.get_by_role("button", name="Capture").wait_for(timeout=60_000)
                pages.append(page)
            fault()
            wf._set(robot="failed", error=f"robot: {EVIL}", message=EVIL, warnings=(EVIL,),
                    robot_events=(RobotEvent("error", 1, "b1", {"message": EVIL}),),
                    outcome=RobotOutcome(("b0",), False, EVIL, ()),
                    decisions=({"decision": "approve", "plan": "h", "who": EVIL, "reason": EVIL, "at": 0.0},))
            for page in pages:
                page.wait_for_function("t => document.body.innerText.replaceAll('\\u2060', '').includes(t)",
                                       arg=EVIL, timeout=30_000)
                page.wait_for_timeout(500)
                assert page.evaluate("() => window.__pwned === undefined")
                assert page.locator("#pwn1, #pwn2").count() == 0
                assert page.locator("a[href*='evil.example'], img[src*='evil.example']").count() == 0
                shown = page.evaluate("() => document.body.innerText").replace("\u2060", "")
                assert shown.count(EVIL) >= 3                 # error, message, warning: every character
            b.close()
    finally:
        app.stop()
        store.close()
    assert fetched == []
