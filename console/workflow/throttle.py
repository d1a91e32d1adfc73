"""The supervisor passphrase's brake: wrong tries slow down that browser and, past a few, everybody else.

The overall brake must not let one attacker lock the real supervisor out (issue 30): a browser
that was already connected when the current run of wrong tries began, and has not failed
itself, is judged by its own record and keeps approving.
"""
from __future__ import annotations

import threading
import time
from typing import Callable


class Throttle:
    """Wrong passphrases slow callers down: per browser and overall, with doubling waits.

    After `client_free` wrong tries in a row a browser waits
    `client_base * 2**(n-1)` s (at most `client_max`) before its next try is
    even compared (a typo costs nothing); after `global_free` wrong tries in a
    row from anywhere, every browser waits `global_base * 2**(k)` s (at most
    `global_max`), except a browser that is *trusted*: connected (`connected()`)
    before the first wrong try of that run and with at most `client_free`
    wrong tries of its own in a row. An attacker's browsers are their own
    record (they failed) or new (connected during the run), so the brake holds
    for them while the supervisor at their own browser can still approve; each
    browser opened before a run began is worth at most `client_free + 1`
    compared tries during it. A right passphrase resets the caller's count
    and the overall one.
    """

    def __init__(self, client_free: int = 2, client_base: float = 0.5, client_max: float = 60.0,
                 global_free: int = 5,
                 global_base: float = 0.5, global_max: float = 300.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.client_free, self.client_base, self.client_max = client_free, client_base, client_max
        self.global_free, self.global_base, self.global_max = global_free, global_base, global_max
        self.clock = clock
        self.lock = threading.Lock()
        self._fails: dict[str, int] = {}
        self._until: dict[str, float] = {}
        self._since: dict[str, float] = {}   # when each live browser connected
        self._global_fails = 0
        self._global_until = 0.0
        self._run_began: float | None = None  # the first wrong try of the current run
        self.throttled = 0           # tries refused without being compared

    def connected(self, client: str) -> None:
        """A browser connected (its view was built): from now on it has a record of its own."""
        with self.lock:
            self._since.setdefault(client, self.clock())

    def disconnected(self, client: str) -> None:
        """A browser went away: forget it (its wait, if any, is kept until it ends)."""
        with self.lock:
            self._since.pop(client, None)
            self._fails.pop(client, None)
            if self._until.get(client, 0.0) <= self.clock():
                self._until.pop(client, None)

    def _trusted(self, client: str) -> bool:
        since = self._since.get(client)
        return (since is not None and self._run_began is not None and since < self._run_began
                and self._fails.get(client, 0) <= self.client_free)

    def check(self, client: str, compare: Callable[[], bool]) -> bool | None:
        """True: right; False: wrong (compared); None: refused unseen (too soon). Atomic per try."""
        with self.lock:
            now = self.clock()
            if now < self._until.get(client, 0.0) or (now < self._global_until and not self._trusted(client)):
                self.throttled += 1
                return None
            if compare():
                self._fails.pop(client, None)
                self._until.pop(client, None)
                self._global_fails = 0
                self._global_until = 0.0
                self._run_began = None
                return True
            n = self._fails[client] = self._fails.get(client, 0) + 1
            if n > self.client_free:
                self._until[client] = now + min(self.client_base * 2 ** (n - 1 - self.client_free),
                                                self.client_max)
            if self._global_fails == 0:
                self._run_began = now
            self._global_fails += 1
            k = self._global_fails - self.global_free
            if k >= 0:
                self._global_until = now + min(self.global_base * 2 ** k, self.global_max)
            return False


__all__ = ["Throttle"]
