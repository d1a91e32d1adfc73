"""The console's websocket refuses foreign origins and its pages forbid framing (console/web/origin_guard.py),
on a real viser server over real sockets. The guard hooks viser's server start: if a viser upgrade
stops starting its server the way the guard expects, the console refuses to start and these fail."""
from __future__ import annotations

import http.client
import socket

import pytest

from safety_kit import fault

@pytest.fixture
def console(tmp_path):
    from shelfpick.console.web.app import ConsoleApp
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    store = SessionStore(tmp_path / "o.sqlite")
    wf = Workflow(None, store, lambda t, s: None, "pw")
    app = ConsoleApp(wf, port=0, allow_origins=("https://proxy.example:8443",))
    yield app
    app.stop()
    store.close()


def websocket(app, origin: str | None):
    """Open the console's websocket as a browser on `origin` would (None: a script, no Origin)."""
    import viser
    from websockets.sync.client import connect

    return connect(f"ws://127.0.0.1:{app.port}/", origin=origin, subprotocols=[f"viser-v{viser.__version__}"],
                   open_timeout=10)


def test_a_foreign_origin_is_refused_before_viser_sees_it_and_the_own_origin_connects(console):
    from websockets.exceptions import InvalidStatus

    app = console
    fault()
    for origin in ("http://evil.example", f"http://127.0.0.1:{app.port + 1}", "null",
                   f"http://localhost.evil.example:{app.port}"):
        with pytest.raises(InvalidStatus) as exc:
            websocket(app, origin)
        assert exc.value.response.status_code == 403, origin
    for origin in (f"http://127.0.0.1:{app.port}", "https://proxy.example:8443", None):
        with websocket(app, origin) as ws:
            assert ws.recv(timeout=10)                         # viser's state arrives


def test_every_page_forbids_framing(console):
    for path in ("/", "/index.html", "/no-such-file"):
        conn = http.client.HTTPConnection("127.0.0.1", console.port, timeout=10)   # one request each
        conn.request("GET", path)
        r = conn.getresponse()
        r.read()
        conn.close()
        assert r.getheader("X-Frame-Options") == "DENY", path
        assert r.getheader("Content-Security-Policy") == "frame-ancestors 'none'", path


def test_same_origin_needs_a_host_name_of_ours_dns_rebinding_is_foreign():
    from shelfpick.console.web.origin_guard import normalize_origin, policy_for

    local = policy_for("127.0.0.1")
    assert local.admits(["http://127.0.0.1:8080"], ["127.0.0.1:8080"])[0]
    assert local.admits(["http://localhost:8080"], ["localhost:8080"])[0]
    assert local.admits([], ["127.0.0.1:8080"])[0]                        # not a browser page
    me = socket.gethostname().lower()
    assert local.admits([f"http://{me}:8080"], [f"{me}:8080"])[0]        # this machine's own name
    # a foreign name resolving to this machine: Origin and Host agree, the name is not ours
    assert local.admits(["http://evil.example:8080"], ["evil.example:8080"]) == \
        (False, "the host name 'evil.example' is not one this console answers as")
    assert not local.admits(["http://127.0.0.1:8081"], ["127.0.0.1:8080"])[0]     # another port
    assert not local.admits(["http://192.168.1.5:8080"], ["192.168.1.5:8080"])[0]  # not our address
    assert not local.admits(["null"], ["127.0.0.1:8080"])[0]
    assert not local.admits(["http://127.0.0.1:8080"] * 2, ["127.0.0.1:8080"])[0]
    every = policy_for("0.0.0.0", ["https://Proxy.example:443/"])
    assert every.admits(["http://192.168.1.5:8080"], ["192.168.1.5:8080"])[0]
    assert every.admits(["https://proxy.example"], ["10.0.0.1:8080"])[0]
    assert normalize_origin("HTTP://[::1]:80") == "http://[::1]"
    for bad in ("ftp://x", "http://x/path", "http://u@x", "x", "http://x:99999"):
        with pytest.raises(ValueError):
            normalize_origin(bad)


def test_a_bad_allowed_origin_is_one_line_before_anything_starts(tmp_path):
    from shelfpick.console.web.app import ConsoleApp, ConsoleError
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    store = SessionStore(tmp_path / "o.sqlite")
    wf = Workflow(None, store, lambda t, s: None, "pw")
    with pytest.raises(ConsoleError, match=r"--allow-origin 'http://x/app': an origin is scheme, host and port"):
        ConsoleApp(wf, port=0, allow_origins=("http://x/app",))
    wf.close()
    store.close()


def test_a_viser_that_no_longer_starts_its_server_through_websockets_serve_is_refused(monkeypatch):
    """Fail closed: if viser stops calling websockets.asyncio.server.serve, the guard is not in place
    and the console must not start unguarded."""
    import viser

    from shelfpick.console.web.origin_guard import OriginGuardError, guarded_viser_server, policy_for

    stopped = []

    class ServesItsOwnWay:                      # a viser whose server starts some other way
        def __init__(self, **kwargs):
            pass

        def stop(self):
            stopped.append(True)

    monkeypatch.setattr(viser, "ViserServer", ServesItsOwnWay)
    fault()
    with pytest.raises(OriginGuardError, match="the origin guard is not in place"):
        guarded_viser_server("127.0.0.1", 0, policy_for("127.0.0.1"))
    assert stopped == [True]
