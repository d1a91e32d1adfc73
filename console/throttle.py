"""The supervisor passphrase's brake: wrong tries slow down that browser and, past a few, everybody."""
from __future__ import annotations

import threading
import time
from typing import Callable


class Throttle:
    """Wrong passphrases slow everybody down: per browser and overall, with doubling waits.

    After `client_free` wrong tries in a row a browser waits
    `client_base * 2**(n-1)` s (at most `client_max`) before its next try is
    even compared (a typo costs nothing); after `global_free`
    wrong tries in a row from anywhere, every browser waits
    `global_base * 2**(k)` s (at most `global_max`). A right passphrase resets
    the caller's count and the overall one.
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
        self._global_fails = 0
        self._global_until = 0.0
        self.throttled = 0           # tries refused without being compared

    def check(self, client: str, compare: Callable[[], bool]) -> bool | None:
        """True: right; False: wrong (compared); None: refused unseen (too soon). Atomic per try."""
        with self.lock:
            now = self.clock()
            if now < self._until.get(client, 0.0) or now < self._global_until:
                self.throttled += 1
                return None
            if compare():
                self._fails.pop(client, None)
                self._until.pop(client, None)
                self._global_fails = 0
                return True
            n = self._fails[client] = self._fails.get(client, 0) + 1
            if n > self.client_free:
                self._until[client] = now + min(self.client_base * 2 ** (n - 1 - self.client_free),
                                                self.client_max)
            self._global_fails += 1
            k = self._global_fails - self.global_free
            if k >= 0:
                self._global_until = now + min(self.global_base * 2 ** k, self.global_max)
            return False



__all__ = ["Throttle"]
