"""The wire of `shelfpick.robot/1`: one JSON object per line, both ways, with caps a peer cannot pass.

Shared by both ends: the console's driver (console/robot/tcp.py) and the
reference controller (robotsim/controller.py).
"""
from __future__ import annotations

import json
import socket
import threading
import time
from typing import Any, Mapping

PROTOCOL = "shelfpick.robot/1"
MAX_LINE = 1 << 20      # bytes in one line
MAX_BLANK = 100         # blank lines tolerated on one connection
MAX_RATE = 200.0        # lines a second a peer may send on average ...
MAX_BURST = 400         # ... after a burst of this many (a robot sends a few a second)


class ProtocolError(Exception):
    """The peer sent something that is not a protocol message."""


class FloodError(ProtocolError):
    """The peer went past a cap (line length, blank lines, line rate): the connection is done for."""


def _no_constant(name: str) -> Any:
    raise ValueError(f"{name} is not JSON")


def _parse_message(line: bytes) -> dict:
    """One protocol message from one line: a JSON object with a string `type`, strict JSON only
    (no NaN/Infinity; nesting or numbers too big for the parser are refused, never a crash)."""
    try:
        msg = json.loads(line, parse_constant=_no_constant)
    except (ValueError, UnicodeDecodeError, RecursionError) as exc:
        raise ProtocolError(f"not JSON: {line[:80]!r} ({str(exc)[:120]})") from None
    if not isinstance(msg, dict) or not isinstance(msg.get("type"), str):
        raise ProtocolError(f"expected an object with a string 'type', got {line[:80]!r}")
    return msg


class LineConn:
    """Line-delimited JSON on a socket: send(dict), recv(timeout) -> dict | None (None = nothing yet).

    A peer cannot make it recurse, buffer without bound or spin: a line over
    MAX_LINE bytes, more than MAX_BLANK blank lines on one connection, or more
    than MAX_RATE lines a second (beyond a burst of MAX_BURST) is a
    ProtocolError, which ends the run.
    """

    def __init__(self, sock: socket.socket, *, max_line: int = MAX_LINE, max_blank: int = MAX_BLANK,
                 max_rate: float = MAX_RATE, max_burst: int = MAX_BURST) -> None:
        self.sock = sock
        self._buf = b""
        self._send_lock = threading.Lock()
        self.max_line, self.max_blank = int(max_line), int(max_blank)
        self.max_rate, self.max_burst = float(max_rate), float(max_burst)
        self.blank_lines = 0
        self._tokens = self.max_burst
        self._refilled = time.monotonic()

    def send(self, msg: Mapping[str, Any]) -> None:
        data = (json.dumps(msg, separators=(",", ":")) + "\n").encode()
        with self._send_lock:
            self.sock.sendall(data)

    def recv(self, timeout: float) -> dict | None:
        """Next message, None if none within `timeout`; ConnectionError on EOF, ProtocolError on abuse."""
        deadline = time.monotonic() + max(timeout, 0.0)
        while True:
            line = self._next_line(deadline)
            if line is None:
                return None
            self._count_line()
            if line.strip():
                return _parse_message(line)
            self.blank_lines += 1
            if self.blank_lines > self.max_blank:
                raise FloodError(f"more than {self.max_blank} blank lines")

    def _next_line(self, deadline: float) -> bytes | None:
        """One raw line (without its newline), None at the deadline."""
        while True:
            nl = self._buf.find(b"\n")
            if nl >= 0:
                if nl > self.max_line:
                    raise FloodError(f"line longer than {self.max_line} bytes")
                line, self._buf = self._buf[:nl], self._buf[nl + 1:]
                return line
            if len(self._buf) > self.max_line:
                raise FloodError(f"line longer than {self.max_line} bytes")
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            self.sock.settimeout(left)
            try:
                chunk = self.sock.recv(65536)
            except socket.timeout:
                return None
            except OSError as exc:
                raise ConnectionError(f"connection lost ({exc})") from None
            if not chunk:
                raise ConnectionError("connection closed by the peer")
            self._buf += chunk

    def _count_line(self) -> None:
        """Token bucket over every line received, blank or not."""
        now = time.monotonic()
        self._tokens = min(self.max_burst, self._tokens + (now - self._refilled) * self.max_rate)
        self._refilled = now
        self._tokens -= 1.0
        if self._tokens < 0:
            raise FloodError(f"more than {self.max_rate:g} lines a second (flood)")

    def close(self) -> None:
        try:
            self.sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
        self.sock.close()



__all__ = ["PROTOCOL", "MAX_LINE", "MAX_BLANK", "MAX_RATE", "MAX_BURST", "ProtocolError", "FloodError", "LineConn"]
