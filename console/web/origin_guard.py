"""Only the console's own pages drive the console: foreign origins are refused, framing is forbidden.

Why this module exists: a page on any other site can open a websocket to a console on the same
machine or network (browsers send no cookies or passwords here, so nothing else stops it) and
press Stop, Capture and Plan, or read plan hashes; a page can also frame the console and trick a
click (issue 30 item 3). viser 1.1.1 serves the page and the websocket itself, accepts any
`Origin` and sends no framing headers, and offers no hook for either.

How: viser's `WebsockServer` starts `websockets.asyncio.server.serve` in its own thread, with
its own `process_request` (the static files) and no `process_response`. While a `ViserServer`
is built (its constructor returns only once that call was made), `guarded_viser_server`
replaces the module attribute `websockets.asyncio.server.serve` by a wrapper that puts
`OriginPolicy` in front of viser's `process_request` (a websocket upgrade from a foreign origin
gets 403 before viser sees it) and adds `X-Frame-Options: DENY` and
`Content-Security-Policy: frame-ancestors 'none'` to every response; then it puts the original
back. Only calls whose handler comes from viser are touched, and nothing of viser's own is
patched. Should a viser upgrade stop opening its server through that call, the guard is not in
place and `guarded_viser_server` raises `OriginGuardError` (the console does not start
unguarded); tests/console/test_origin.py fails then too.

Same origin means: the `Origin` is the address the request was sent to (its `Host` header), and
that host is one this console answers as (a loopback name, the `--host` it listens on, this
machine's name, and, when it listens on every address, any IP address), so a foreign name that
resolves to this machine (DNS rebinding) is foreign. Other origins come from `--allow-origin` or
the cell file's `safety.allow_origins` (a reverse proxy's address, say). A request with no
`Origin` is not from a browser page and is let through (a script can send any header anyway).
"""
from __future__ import annotations

import http
import ipaddress
import logging
import socket
import threading
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable
from urllib.parse import urlsplit

from shelfpick.perception.errors import ShelfpickError

if TYPE_CHECKING:
    import viser

log = logging.getLogger(__name__)

LOOPBACK = frozenset({"127.0.0.1", "localhost", "::1"})
WILDCARD = frozenset({"0.0.0.0", "::", ""})
FRAME_HEADERS = (("X-Frame-Options", "DENY"), ("Content-Security-Policy", "frame-ancestors 'none'"))
_DEFAULT_PORT = {"http": 80, "https": 443}
_INSTALL = threading.Lock()    # one server built at a time while the wrapper is in place


class OriginGuardError(ShelfpickError):
    """The guard could not be put in front of viser's server: the console must not start."""


def normalize_origin(text: str) -> str:
    """`scheme://host[:port]` as a browser sends it in `Origin` (default port dropped, host lower case);
    ValueError with the reason for anything else (a path, a query, user info, another scheme)."""
    raw = str(text).strip()
    try:
        parts = urlsplit(raw)
        port = parts.port
    except ValueError as exc:
        raise ValueError(f"not an origin ({exc})") from None
    if parts.scheme not in _DEFAULT_PORT or not parts.hostname:
        raise ValueError("expected http://HOST[:PORT] or https://HOST[:PORT]")
    if parts.path not in ("", "/") or parts.query or parts.fragment or "@" in parts.netloc:
        raise ValueError("an origin is scheme, host and port only (no path, query or user)")
    host = parts.hostname.lower()
    host = f"[{host}]" if ":" in host else host
    return f"{parts.scheme}://{host}" + (f":{port}" if port not in (None, _DEFAULT_PORT[parts.scheme]) else "")


@dataclass(frozen=True)
class OriginPolicy:
    """Which browser origins may open the console's websocket (see the module docstring)."""

    allowed: frozenset[str] = frozenset()     # normalized origins given by the cell file or --allow-origin
    hosts: frozenset[str] = LOOPBACK          # host names the console answers as (same origin)
    any_ip: bool = False                      # listening on every address: any IP literal is one of ours

    def admits(self, origins: list[str], hosts: list[str]) -> tuple[bool, str]:
        """(admitted, why) for a websocket upgrade with these `Origin` and `Host` header values."""
        if not origins:
            return True, "no Origin: not a browser page"
        if len(origins) > 1 or len(hosts) != 1:
            return False, "several Origin or Host headers"
        try:
            origin = normalize_origin(origins[0])
        except ValueError:
            return False, "an opaque or malformed origin"
        if origin in self.allowed:
            return True, "an allowed origin"
        scheme = origin.split(":", 1)[0]
        try:
            sent_to = normalize_origin(f"{scheme}://{hosts[0]}")
        except ValueError:
            return False, "a malformed Host"
        if origin != sent_to:
            return False, "a foreign origin"
        name = urlsplit(sent_to).hostname or ""
        if name in self.hosts or (self.any_ip and _is_ip(name)):
            return True, "the same origin"
        return False, f"the host name {name!r} is not one this console answers as"


def _is_ip(name: str) -> bool:
    try:
        ipaddress.ip_address(name)
    except ValueError:
        return False
    return True


def policy_for(host: str, allow_origins: Iterable[str] = ()) -> OriginPolicy:
    """The policy for a console listening on `host` with these extra origins (ValueError names a bad one)."""
    allowed = set()
    for o in allow_origins:
        try:
            allowed.add(normalize_origin(o))
        except ValueError as exc:
            raise ValueError(f"{o!r}: {exc}") from None
    bind = host.strip("[]").lower()
    names = set(LOOPBACK) | {bind, socket.gethostname().lower()}
    if bind in WILDCARD:           # a DNS look-up, only where the console answers on every address
        names.add(socket.getfqdn().lower())
    return OriginPolicy(frozenset(allowed), frozenset(n for n in names if n), bind in WILDCARD)


def _guarded_request(policy: OriginPolicy, inner: Callable[..., Any] | None) -> Callable[..., Any]:
    """viser's `process_request` behind the origin check of websocket upgrades."""
    def process_request(connection: Any, request: Any) -> Any:
        if any(v.strip().lower() == "websocket" for v in request.headers.get_all("Upgrade")):
            origins, hosts = request.headers.get_all("Origin"), request.headers.get_all("Host")
            ok, why = policy.admits(origins, hosts)
            if not ok:
                log.warning("console: refused a websocket from origin %r to host %r: %s",
                            origins[:1], hosts[:1], why)
                return connection.respond(http.HTTPStatus.FORBIDDEN, f"Forbidden: {why}.\n")
        return inner(connection, request) if inner is not None else None
    return process_request


def _framing_forbidden(inner: Callable[..., Any] | None) -> Callable[..., Any]:
    """`process_response` that adds FRAME_HEADERS to every response (after viser's own, if it has one)."""
    def process_response(connection: Any, request: Any, response: Any) -> Any:
        out = inner(connection, request, response) if inner is not None else None
        target = out if out is not None else response
        for name, value in FRAME_HEADERS:
            if target.headers.get_all(name):
                del target.headers[name]
            target.headers[name] = value
        return out
    return process_response


def guarded_viser_server(host: str, port: int, policy: OriginPolicy, verbose: bool = False) -> viser.ViserServer:
    """A `viser.ViserServer` whose websocket refuses foreign origins and whose pages cannot be framed."""
    import viser
    import websockets.asyncio.server as ws_server

    with _INSTALL:
        real = ws_server.serve
        guarded: list[bool] = []

        def serve(handler: Any, *args: Any, **kwargs: Any) -> Any:
            if str(getattr(handler, "__module__", "")).startswith("viser."):
                kwargs["process_request"] = _guarded_request(policy, kwargs.get("process_request"))
                kwargs["process_response"] = _framing_forbidden(kwargs.get("process_response"))
                guarded.append(True)
            return real(handler, *args, **kwargs)

        ws_server.serve = serve
        try:
            server = viser.ViserServer(host=host, port=port, verbose=verbose)
        finally:
            ws_server.serve = real
    if not guarded:
        server.stop()
        raise OriginGuardError(f"viser {viser.__version__} did not open its server through "
                               "websockets.asyncio.server.serve: the origin guard is not in place, so the "
                               "console does not start (see console/web/origin_guard.py)")
    return server


__all__ = ["OriginPolicy", "OriginGuardError", "FRAME_HEADERS", "normalize_origin", "policy_for",
           "guarded_viser_server"]
