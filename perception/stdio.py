"""Keep C libraries' printf() off our stdout: a command's stdout carries only what was asked for.

pybullet's C code prints "argv[0]=" on fd 1 at every connect and its build time
on fd 2 when imported. File descriptors belong to the whole process, so
pointing fd 1 and 2 at /dev/null around a connect also swallows whatever any
other thread writes meanwhile. In the console (threads capture, plan and run
the robot while the main thread prints the URL and the log) that lost lines:
the URL line's newline once, and a warning could have gone the same way. Two
rules follow:

- redirections that overlap (any threads) are counted: the first sets the file
  descriptors and the last puts them back, so two threads never interleave
  their save/restore (which could leave fd 1 at /dev/null for good);
- a long-running process with threads calls `c_output_detached()` once: Python's
  stdout moves to a private copy of fd 1, fd 1 itself goes to /dev/null, and
  the redirections then change no file descriptor at all.

The counts and the saved descriptors are the state of one `StdioGuard`, which this module
creates when it is first imported (`STDIO`); the functions below are that guard's.
"""
from __future__ import annotations

import os
import sys
import threading
from contextlib import AbstractContextManager, contextmanager
from typing import Iterator


def _point(fd: int, to: str | int) -> None:
    target = os.open(to, os.O_WRONLY) if isinstance(to, str) else to
    os.dup2(target, fd)
    if isinstance(to, str):
        os.close(target)


class StdioGuard:
    """Who points fd 1 and 2 elsewhere, and when: the count of redirections in force (all
    threads), the descriptors they saved, and whether C output is detached.

    One per process, made by this module at import (`STDIO`), and every redirection goes
    through it: file descriptors 1 and 2 belong to the process, not to an object, so a second
    guard would count only its own redirections and could put fd 1 back in the middle of the
    other's (the lost lines and the stdout left at /dev/null that this guard exists to stop).
    Its state changes only under its own lock."""

    def __init__(self) -> None:
        self._cond = threading.Condition(threading.Lock())
        self._depth = 0                             # redirections in force (all threads)
        self._saved: list[tuple[int, int]] = []     # (fd, copy of what it was) while _depth > 0
        self._detached = 0                          # > 0 while detached() is in force

    @contextmanager
    def redirected(self, stdout_to: str | int | None, stderr_to: str | int | None) -> Iterator[None]:
        """fd 1 / fd 2 sent to a path or another fd (None: left alone) for the block. Inside another
        redirection, or while detached, nothing changes (C output is already off stdout)."""
        with self._cond:
            if self._depth == 0 and not self._detached:
                sys.stdout.flush()
                sys.stderr.flush()
                for fd, to in ((1, stdout_to), (2, stderr_to)):
                    if to is not None:
                        self._saved.append((fd, os.dup(fd)))
                        _point(fd, to)
            self._depth += 1
        try:
            yield
        finally:
            with self._cond:
                self._depth -= 1
                if self._depth == 0:
                    sys.stdout.flush()
                    sys.stderr.flush()
                    while self._saved:
                        fd, copy = self._saved.pop()
                        os.dup2(copy, fd)
                        os.close(copy)
                    self._cond.notify_all()

    @contextmanager
    def quiet(self) -> Iterator[None]:
        """File descriptors 1 and 2 sent to /dev/null (pybullet's C code printf()s on them); nothing
        changes while `detached()` is in force (C output already goes nowhere)."""
        with self.redirected(os.devnull, os.devnull):
            yield

    @contextmanager
    def detached(self) -> Iterator[None]:
        """For a process with threads: Python's stdout keeps the terminal (a private copy of fd 1),
        fd 1 goes to /dev/null for C code, and pybullet is imported quietly once. Restored on exit.

        Enter it before the threads that write start (they look `sys.stdout` up when they print);
        a thread inside a redirection is waited for. Inside another detachment it changes nothing."""
        if self._detached:
            yield
            return
        with self.redirected(os.devnull, os.devnull):
            import pybullet  # noqa: F401 - its build-time banner, printed on import, goes nowhere
        with self._cond:
            self._cond.wait_for(lambda: self._depth == 0)   # no thread is between a redirect and its restore
            old = sys.stdout
            old.flush()
            stream = open(os.dup(1), "w", encoding=old.encoding, errors=old.errors, buffering=1,  # noqa: SIM115
                          closefd=True)
            saved = os.dup(1)
            _point(1, os.devnull)
            sys.stdout = stream
            self._detached += 1
        try:
            yield
        finally:
            with self._cond:
                self._detached -= 1
                stream.flush()
                if sys.stdout is stream:
                    sys.stdout = old
                os.dup2(saved, 1)
                os.close(saved)
                stream.close()


STDIO = StdioGuard()   # the process's one guard (see StdioGuard): created here, once, at import


def redirected_fds(stdout_to: str | int | None, stderr_to: str | int | None) -> AbstractContextManager[None]:
    """`STDIO.redirected`: fd 1 / fd 2 sent to a path or another fd (None: left alone) for the block."""
    return STDIO.redirected(stdout_to, stderr_to)


def quiet_stdio() -> AbstractContextManager[None]:
    """`STDIO.quiet`: fd 1 and 2 sent to /dev/null for the block (pybullet's C printf()s)."""
    return STDIO.quiet()


def c_output_detached() -> AbstractContextManager[None]:
    """`STDIO.detached`: for a process with threads, C output off stdout for the block (see there)."""
    return STDIO.detached()
