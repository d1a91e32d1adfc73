"""Another web page cannot drive the console (issue 30 item 3), in headless Chromium: a page served
from another origin (an http.server on another 127.0.0.1 port) cannot open the console's websocket
and cannot show the console in a frame, while the console on its own origin still works.
Marker `browser` (runs by default, like tests/console/test_browser.py)."""
from __future__ import annotations

import functools
import threading
import time
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest

from safety_kit import fault

pytestmark = pytest.mark.browser
CHROMIUM = "/usr/bin/chromium"
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]

OPENER = """<!doctype html><title>elsewhere</title><script>
window.__ws = "pending";
const ws = new WebSocket("ws://127.0.0.1:%(port)d/", ["viser-v%(version)s"]);
ws.onopen = () => { window.__ws = "open"; };
ws.onclose = (e) => { if (window.__ws !== "open") window.__ws = "refused " + e.code; };
</script>"""
FRAMER = """<!doctype html><title>framer</title>
<iframe id="console" src="http://127.0.0.1:%(port)d/" width="900" height="600"></iframe>"""


class _Quiet(SimpleHTTPRequestHandler):
    def log_message(self, *args):      # no request lines in the test output
        pass


@pytest.fixture
def sites(tmp_path):
    """The console on one port, another site (the attacker's pages) on another."""
    import viser

    from shelfpick.console.web.app import ConsoleApp
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    if not Path(CHROMIUM).exists():
        pytest.skip(f"{CHROMIUM} missing (make test installs it)")
    store = SessionStore(tmp_path / "o.sqlite")
    wf = Workflow(None, store, lambda t, s: None, "pw")
    app = ConsoleApp(wf, port=0)
    www = tmp_path / "www"
    www.mkdir()
    for name, page in (("open.html", OPENER), ("frame.html", FRAMER)):
        (www / name).write_text(page % {"port": app.port, "version": viser.__version__})
    other = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_Quiet, directory=str(www)))
    threading.Thread(target=other.serve_forever, daemon=True).start()
    try:
        yield app, wf, f"http://127.0.0.1:{other.server_address[1]}"
    finally:
        other.shutdown()
        other.server_close()
        app.stop()
        store.close()


def until(cond, timeout: float, what: str):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        v = cond()
        if v:
            return v
        time.sleep(0.1)
    raise AssertionError(f"timed out waiting for {what}")


def test_other_origins_cannot_open_the_websocket_or_frame_the_console_and_its_own_page_works(sites):
    from playwright.sync_api import sync_playwright

    app, wf, elsewhere = sites
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=ARGS, headless=True)
        try:
            ctx = b.new_context()
            fault()
            page = ctx.new_page()
            page.goto(f"{elsewhere}/open.html")
            page.wait_for_function("() => window.__ws !== 'pending'", timeout=30_000)
            assert page.evaluate("() => window.__ws") == "refused 1006"    # the handshake got 403

            fault()
            framer = ctx.new_page()
            framer.goto(f"{elsewhere}/frame.html")
            frame = until(lambda: next((f for f in framer.frames if f is not framer.main_frame), None), 30,
                          "the frame")
            # Chromium replaces a frame whose response forbids framing by its error page
            until(lambda: frame.url.startswith("chrome-error:"), 30, f"a blocked frame (it shows {frame.url})")
            framer.wait_for_timeout(2000)
            assert app.views == {}                      # nothing of the console ran in the frame

            own = ctx.new_page()                        # the console on its own origin still works
            own.goto(app.url)
            own.get_by_role("button", name="Capture").wait_for(timeout=60_000)
            until(lambda: len(app.views) == 1, 30, "the console's own page to connect")
            own.get_by_role("button", name="Stop robot").click()
            until(lambda: wf.state.message == "robot is not running", 30, "Stop robot to reach the console")
            ctx.close()
        finally:
            b.close()
