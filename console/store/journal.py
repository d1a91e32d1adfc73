"""Records of a robot run that must reach the database, in order, however long it is locked.

Why: a robot that moved cannot be un-moved. When the database is locked (or
full, or read-only) as an `ack` arrives, the run is stopped at once (no
further step goes out), but the `ack`, what the robot says next and the
run's outcome must still be committed: dropping them would leave the session
`executing` for ever and a restart would call the moved step never sent.

`RecordJournal.record(what, fn, *args)` commits at once when nothing is
waiting; otherwise (or when the commit fails) the record joins a queue that
one background thread retries in order, with a bounded backoff, until each
one is committed. `on_status` hears what is waiting and why (the page shows
it), and once more with None when the queue is empty again. While anything
waits, `pending()` is non-zero: the console refuses to start another run.
"""
from __future__ import annotations

import logging
import threading
import time
from collections import deque
from dataclasses import dataclass
from typing import Any, Callable

log = logging.getLogger("shelfpick.console.store.sessions")

FIRST_WAIT = 0.1     # s before the first retry; doubled after each failure ...
MAX_WAIT = 2.0       # ... up to this (each try may also wait the store's busy timeout)

Status = Callable[["JournalStatus | None"], None]


@dataclass(frozen=True)
class JournalStatus:
    """What is waiting: how many records, the first one, the attempts so far, the last error."""

    waiting: int
    first: str
    attempts: int
    error: str
    retry_in: float

    def text(self) -> str:
        return (f"database: {self.waiting} record(s) of the robot run not yet committed (first: {self.first}); "
                f"retrying every {self.retry_in:g} s (attempt {self.attempts}): {self.error}; "
                f"nothing more is sent to the robot until they are")


@dataclass(frozen=True)
class _Entry:
    what: str
    fn: Callable[..., Any]
    args: tuple


class RecordJournal:
    """Ordered, retried-until-committed writes (thread safe; one retry thread while anything waits)."""

    def __init__(self, on_status: Status | None = None, first_wait: float = FIRST_WAIT,
                 max_wait: float = MAX_WAIT) -> None:
        self._lock = threading.Lock()
        self._queue: deque[_Entry] = deque()
        self._on_status = on_status
        self._first_wait, self._max_wait = float(first_wait), float(max_wait)
        self._thread: threading.Thread | None = None
        self._closed = False
        self._idle = threading.Condition(self._lock)
        self.attempts = 0          # retries made for the records now waiting

    def pending(self) -> int:
        with self._lock:
            return len(self._queue)

    def record(self, what: str, fn: Callable[..., Any], *args: Any) -> bool:
        """Commit now (True), or queue behind what waits and retry until committed (False)."""
        with self._lock:
            if self._closed:
                raise RuntimeError(f"{what}: the journal is closed")
            if not self._queue:
                try:
                    fn(*args)
                    return True
                except Exception as exc:  # noqa: BLE001 - sqlite3, StoreError, OSError alike
                    error = str(exc)
            else:
                error = None
            self._queue.append(_Entry(what, fn, args))
            first, waiting = self._queue[0].what, len(self._queue)
            if self._thread is None:
                self.attempts = 0
                self._thread = threading.Thread(target=self._retry, name="shelfpick-journal", daemon=True)
                self._thread.start()
        if error is not None:
            log.warning("could not record %s (%s): retrying until it is", what, error)
            self._tell(JournalStatus(waiting, first, 0, error, self._first_wait))
        return False

    def _tell(self, status: JournalStatus | None) -> None:
        if self._on_status is None:
            return
        try:
            self._on_status(status)
        except Exception:  # noqa: BLE001 - a broken view must not stop the retries
            log.exception("journal status listener failed")

    def _retry(self) -> None:
        wait = self._first_wait
        while True:
            time.sleep(wait)
            with self._lock:
                if self._closed or not self._queue:
                    self._thread = None
                    self._idle.notify_all()
                    return
                head = self._queue[0]
            try:
                head.fn(*head.args)
                error = None
            except Exception as exc:  # noqa: BLE001
                error = str(exc)
            with self._lock:
                self.attempts += 1
                if error is None:
                    self._queue.popleft()
                    wait = 0.0 if self._queue else wait
                    done = not self._queue
                    if done:
                        self._thread = None
                        self._idle.notify_all()
                    status = None if done else JournalStatus(len(self._queue), self._queue[0].what,
                                                             self.attempts, "(retrying)", wait)
                else:
                    wait = min(self._max_wait, max(wait, self._first_wait) * 2)
                    done = False
                    status = JournalStatus(len(self._queue), head.what, self.attempts, error, wait)
            if error is None:
                log.warning("recorded %s after %d attempt(s)", head.what, self.attempts)
            if done:
                self._tell(None)
                return
            if error is not None:
                self._tell(status)

    def wait_empty(self, timeout: float) -> bool:
        """Wait up to `timeout` s for every waiting record to be committed; True when none waits."""
        end = time.monotonic() + timeout
        with self._lock:
            while self._queue and not self._closed:
                left = end - time.monotonic()
                if left <= 0:
                    break
                self._idle.wait(min(left, 0.1))
            return not self._queue

    def close(self) -> list[str]:
        """Stop retrying; what is still waiting (a restart's recovery marks that run interrupted)."""
        with self._lock:
            self._closed = True
            left = [e.what for e in self._queue]
            self._idle.notify_all()
        if left:
            log.warning("closing with %d record(s) not committed (%s): the next start marks the run "
                        "interrupted and its sent steps' outcome unknown", len(left), ", ".join(left))
        return left


__all__ = ["RecordJournal", "JournalStatus", "FIRST_WAIT", "MAX_WAIT"]
