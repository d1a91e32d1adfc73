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
"""
from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager
from typing import Iterator

_COND = threading.Condition(threading.Lock())
_depth = 0                      # redirections in force (all threads)
_saved: list[tuple[int, int]] = []   # (fd, copy of what it was) while _depth > 0
_detached = 0                   # > 0 while c_output_detached() is in force


def _point(fd: int, to: str | int) -> None:
    target = os.open(to, os.O_WRONLY) if isinstance(to, str) else to
    os.dup2(target, fd)
    if isinstance(to, str):
        os.close(target)


@contextmanager
def redirected_fds(stdout_to: str | int | None, stderr_to: str | int | None) -> Iterator[None]:
    """fd 1 / fd 2 sent to a path or another fd (None: left alone) for the block. Inside another
    redirection, or while detached, nothing changes (C output is already off stdout)."""
    global _depth
    with _COND:
        if _depth == 0 and not _detached:
            sys.stdout.flush()
            sys.stderr.flush()
            for fd, to in ((1, stdout_to), (2, stderr_to)):
                if to is not None:
                    _saved.append((fd, os.dup(fd)))
                    _point(fd, to)
        _depth += 1
    try:
        yield
    finally:
        with _COND:
            _depth -= 1
            if _depth == 0:
                sys.stdout.flush()
                sys.stderr.flush()
                while _saved:
                    fd, copy = _saved.pop()
                    os.dup2(copy, fd)
                    os.close(copy)
                _COND.notify_all()


@contextmanager
def quiet_stdio() -> Iterator[None]:
    """File descriptors 1 and 2 sent to /dev/null (pybullet's C code printf()s on them); nothing
    changes while `c_output_detached()` is in force (C output already goes nowhere)."""
    with redirected_fds(os.devnull, os.devnull):
        yield


@contextmanager
def c_output_detached() -> Iterator[None]:
    """For a process with threads: Python's stdout keeps the terminal (a private copy of fd 1),
    fd 1 goes to /dev/null for C code, and pybullet is imported quietly once. Restored on exit.

    Enter it before the threads that write start (they look `sys.stdout` up when they print);
    a thread inside a redirection is waited for. Inside another detachment it changes nothing."""
    global _detached
    if _detached:
        yield
        return
    with redirected_fds(os.devnull, os.devnull):
        import pybullet  # noqa: F401 - its build-time banner, printed on import, goes nowhere
    with _COND:
        _COND.wait_for(lambda: _depth == 0)     # no thread is between a redirect and its restore
        old = sys.stdout
        old.flush()
        stream = open(os.dup(1), "w", encoding=old.encoding, errors=old.errors, buffering=1,  # noqa: SIM115
                      closefd=True)
        saved = os.dup(1)
        _point(1, os.devnull)
        sys.stdout = stream
        _detached += 1
    try:
        yield
    finally:
        with _COND:
            _detached -= 1
            stream.flush()
            if sys.stdout is stream:
                sys.stdout = old
            os.dup2(saved, 1)
            os.close(saved)
            stream.close()
