"""Approve is bound to the plan on the supervisor's screen (issue 30 item 2), in headless Chromium.

The supervisor reviews a plan, types the passphrase and ticks the risk; the operator re-plans.
The click that follows approves nothing: the acknowledgements were cleared when the plan under
review changed, and the page says so. A click that leaves while the screen still shows the old
plan (its update held back) carries the old plan's hash and is refused with a message. Typed
again for the plan shown, the approval runs exactly that plan. Marker `browser`.
"""
from __future__ import annotations

import pytest

from safety_kit import fault
from test_browser import (PASS, bottom_left, browser, console, fill_text, open_page, press, tick,  # noqa: F401
                          until, wait_text)

pytestmark = pytest.mark.browser


def field(page, label: str, kind: str = "input"):
    return page.locator(f'xpath=//label[text()="{label}"]/ancestor::div[contains(@class,"mantine-Flex-root")][1]'
                        f'//{kind}')


def acknowledge(page, view) -> None:
    """What the supervisor does for the plan on the screen: type the passphrase, tick the risk."""
    fill_text(page, "Passphrase", PASS)
    until(lambda: view.passphrase.value == PASS, 10, "passphrase typed")
    tick(page, "Accept predicted risk")
    until(lambda: view.accept_risk.value, 10, "risk ticked")


def test_a_replan_clears_the_acknowledgements_and_a_stale_click_is_refused(browser, console):
    app, wf, store = console
    ctx = browser.new_context(viewport={"width": 1000, "height": 900})
    try:
        page, view = open_page(ctx, app)
        st = wf.capture()
        assert st.error is None and st.scene.boxes, st.error
        wf.select_target(bottom_left(st.scene))
        wf.plan("extract", wait=True)
        first = wf.state.plans["physics"]
        press(page, "Supervisor", role="tab")
        wait_text(page, f"{first.hash}: {' → '.join(first.plan.sequence)}")   # the plan under review
        acknowledge(page, view)

        wf.plan("clear", wait=True)                       # the operator re-plans meanwhile
        second = wf.state.plans["physics"]
        assert second.hash != first.hash
        wait_text(page, second.hash)
        fault()
        press(page, "Approve")                            # the click the supervisor meant for the old plan
        # refused: the passphrase is gone (or, for a plan predicted unsafe, first the tick)
        until(lambda: wf.state.approved is not None or wf.state.robot != "idle" or page.evaluate(
            "() => /type the supervisor passphrase|tick .Accept predicted risk/.test(document.body.innerText)"),
            30, "an answer to the click")
        assert wf.state.approved is None and wf.state.robot == "idle", wf.state.message
        assert field(page, "Passphrase").input_value() == ""              # nothing carried over
        assert not field(page, "Accept predicted risk", "input[@type='checkbox']").is_checked()
        wait_text(page, f"{second.hash}: {' → '.join(second.plan.sequence)}")

        acknowledge(page, view)                           # for the plan now shown
        fault()
        with view.lock:                                   # the page's next update is held back
            wf.plan("extract", wait=True)
            third = wf.state.plans["physics"]
            press(page, "Approve")                        # the screen still shows `second`
            wait_text(page, "the physics plan changed since it was shown")
        assert wf.state.approved is None and wf.state.robot == "idle"
        assert not [d for d in store.load_session(st.session_id).decisions if d["decision"] == "approve"]
        wait_text(page, f"{third.hash}: {' → '.join(third.plan.sequence)}")
        until(lambda: view.passphrase.value == "" and not view.accept_risk.value, 10, "acknowledgements cleared")

        acknowledge(page, view)
        press(page, "Approve")
        st = until(lambda: wf.state.robot in ("done", "failed", "stopped") and wf.state, 60, "robot run")
        assert st.outcome is not None and st.outcome.plan == third.hash
        assert [(d["decision"], d["plan_hash"]) for d in store.load_session(st.session_id).decisions] \
            == [("approve", third.hash)]
    finally:
        ctx.close()
