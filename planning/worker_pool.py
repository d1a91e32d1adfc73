"""Worker processes that hold a Predictor's sample worlds: created, owned and closed by the caller.

A `WorkerPool` starts its processes with the forkserver (or spawn) start method,
never by forking the caller: the console calls the planner from viser's thread
pool, and a fork there copies locks held by other threads. A Predictor leases
some workers for its life and gives them back; the pool keeps them (their
imports and their Bullet clients are paid once) until its owner closes it.

Each message to a worker is a small frozen dataclass; each answer a `Reply`.
As with any spawn/forkserver start, a script that plans with workers must keep
its top-level code under ``if __name__ == "__main__":`` (a worker imports the
script's main module; unguarded code would run again there).
"""
from __future__ import annotations

import multiprocessing as mp
import threading
from collections import deque
from dataclasses import dataclass, replace
from typing import Any, Hashable, Sequence

from shelfpick.perception.scene import Scene
from shelfpick.planning.bullet_clients import ClientPool
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.sample_worlds import DrawSummary, SampleWorlds
from shelfpick.planning.uncertainty import Uncertainty


@dataclass(frozen=True)
class Build:
    """Build these sample worlds (and drop any held before)."""

    scene: Scene
    seed: int
    config: PhysicsConfig
    indices: tuple[int, ...]
    model: Uncertainty


@dataclass(frozen=True)
class Extend:
    """Build these sample worlds as well, beside the ones held."""

    indices: tuple[int, ...]


@dataclass(frozen=True)
class Pull:
    """Pull `box` with `removed` taken away in the held worlds `which`."""

    removed: frozenset[str]
    box: str
    which: tuple[int, ...]


@dataclass(frozen=True)
class Preview:
    """Run `sequence` in world `sample`, recording frames."""

    sequence: tuple[str, ...]
    sample: int


@dataclass(frozen=True)
class Release:
    """Close the held worlds; wait for the next Build."""


@dataclass(frozen=True)
class Reply:
    value: Any = None
    error: BaseException | None = None


def _answer(worlds: SampleWorlds | None, msg: Any) -> Reply:
    if isinstance(msg, Extend):
        return Reply({i: DrawSummary.of(d) for i, d in worlds.add(msg.indices).items()})  # type: ignore[union-attr]
    if isinstance(msg, Pull):
        return Reply({i: replace(worlds.pull(i, msg.removed, msg.box), frames=())  # type: ignore[union-attr]
                      for i in msg.which})
    if isinstance(msg, Preview):
        return Reply(worlds.preview(msg.sequence, msg.sample))  # type: ignore[union-attr]
    raise TypeError(f"unknown message {msg!r}")


def serve(conn) -> None:
    """A worker's life: hold one Predictor's share of the sample worlds at a time.

    The worker owns one `ClientPool` for its life, so the Bullet clients of the worlds
    it closes are reused by the next Build.
    """
    worlds: SampleWorlds | None = None
    with ClientPool() as clients:
        try:
            while True:
                msg = conn.recv()
                if isinstance(msg, Build):
                    if worlds is not None:
                        worlds.close()
                    try:
                        worlds = SampleWorlds(msg.scene, msg.seed, msg.config, msg.indices, msg.model,
                                              clients)
                    except BaseException as exc:  # reported to the parent, which raises it
                        worlds = None
                        conn.send(Reply(error=exc))
                        continue
                    conn.send(Reply({i: DrawSummary.of(d) for i, d in worlds.draws.items()}))
                elif isinstance(msg, Release):
                    if worlds is not None:
                        worlds.close()
                    worlds = None
                elif msg is None:
                    break
                else:
                    try:
                        reply = _answer(worlds, msg)
                    except Exception as exc:  # noqa: BLE001 - reported to the parent, which raises it
                        reply = Reply(error=exc)
                    conn.send(reply)
        except (EOFError, KeyboardInterrupt):
            pass
        finally:
            if worlds is not None:
                worlds.close()


class Worker:
    """One worker process and the parent's end of its pipe."""

    def __init__(self, ctx) -> None:
        self.conn, child = ctx.Pipe()
        self.proc = ctx.Process(target=serve, args=(child,), daemon=True)
        self.proc.start()
        child.close()

    def send(self, msg: Any) -> None:
        self.conn.send(msg)

    def recv(self) -> Any:
        """The answer's value; the worker's exception is raised here."""
        reply = self.conn.recv()
        if reply.error is not None:
            raise reply.error
        return reply.value

    def alive(self) -> bool:
        return self.proc.is_alive()

    def stop(self, timeout: float = 5.0) -> None:
        try:
            self.conn.send(None)
        except (OSError, BrokenPipeError):
            pass
        self.proc.join(timeout=timeout)
        self.kill()

    def kill(self) -> None:
        if self.proc.is_alive():
            self.proc.terminate()
            self.proc.join(timeout=5)
        self.conn.close()


def _context(method: str | None):
    methods = mp.get_all_start_methods()
    name = method or ("forkserver" if "forkserver" in methods else "spawn")
    ctx = mp.get_context(name)
    if name == "forkserver":
        # the fork server imports the planner once; every worker is then a cheap fork of it
        ctx.set_forkserver_preload(["shelfpick.planning.worker_pool"])
    return ctx


class Outbox:
    """Messages sent to leased workers whose replies are not read yet, oldest first per worker.

    A worker answers its messages in order, so several can be in flight on one pipe (a batch of
    pulls, more worlds then the pulls in them) and each reply is matched to the oldest tag still
    pending there. Whoever holds the workers `drain`s it before handing them on: a reply left in a
    pipe would be read as the answer to the next owner's first message.
    """

    def __init__(self) -> None:
        self._pending: dict[Worker, deque] = {}

    def send(self, w: Worker, msg: Any, tag: Hashable) -> None:
        w.send(msg)
        self._pending.setdefault(w, deque()).append(tag)

    def pending(self, w: Worker) -> int:
        return len(self._pending.get(w, ()))

    def oldest(self, w: Worker) -> Hashable:
        """The tag of `w`'s oldest pending message (there must be one)."""
        return self._pending[w][0]

    def read(self, w: Worker) -> tuple[Hashable, Any]:
        """(tag, value) of `w`'s oldest pending message; the worker's exception is raised here
        (its reply read all the same)."""
        tag = self._pending[w][0]
        try:
            value = w.recv()
        except (EOFError, OSError, KeyboardInterrupt):   # the pipe's state is unknown
            raise
        except Exception:
            self._pending[w].popleft()
            raise
        self._pending[w].popleft()
        return tag, value

    def drain(self, workers: Sequence[Worker]) -> bool:
        """Read and drop every pending reply of `workers`; False if a pipe broke (the worker is
        then not to be reused). A worker's reported exception is dropped with its reply."""
        ok = True
        for w in workers:
            while self.pending(w):
                try:
                    self.read(w)
                except (EOFError, OSError, KeyboardInterrupt):
                    self._pending.pop(w, None)
                    ok = False
                    break
                except Exception:  # noqa: BLE001 - nobody waits for this answer any more
                    pass
        return ok


class WorkerPool:
    """Up to `size` idle workers kept for the next Predictor; close it when done (or use `with`)."""

    def __init__(self, size: int = 2, *, method: str | None = None) -> None:
        if method == "fork":
            raise ValueError("a WorkerPool never forks its caller: use 'forkserver' or 'spawn'")
        self.size = max(1, int(size))
        self._ctx = _context(method)
        self._idle: list[Worker] = []
        self._leased: set[Worker] = set()
        self._lock = threading.Lock()
        self._closed = False

    def lease(self, n: int) -> list[Worker]:
        """`n` workers for one Predictor (idle ones first, new ones started as needed)."""
        with self._lock:
            if self._closed:
                raise RuntimeError("the worker pool is closed")
            out: list[Worker] = []
            while self._idle and len(out) < n:
                w = self._idle.pop()
                if w.alive():
                    out.append(w)
                else:
                    w.kill()
            self._leased.update(out)
        out += [Worker(self._ctx) for _ in range(n - len(out))]
        with self._lock:
            self._leased.update(out)
        return out

    def give_back(self, workers: Sequence[Worker], broken: bool = False) -> None:
        """Workers a Predictor is done with; `broken` ones (a reply may be left in the pipe) are stopped."""
        for w in workers:
            with self._lock:
                self._leased.discard(w)
                keep = not broken and not self._closed and len(self._idle) < self.size and w.alive()
            if not keep:
                if broken:
                    w.kill()
                else:
                    w.stop()
                continue
            try:
                w.send(Release())
            except (OSError, BrokenPipeError):
                w.kill()
                continue
            with self._lock:
                self._idle.append(w)

    def pids(self) -> list[int]:
        with self._lock:
            return sorted(w.proc.pid for w in self._idle + list(self._leased))

    def close(self) -> None:
        with self._lock:
            self._closed = True
            workers = self._idle + list(self._leased)
            self._idle, self._leased = [], set()
        for w in workers:
            w.stop()

    def __enter__(self) -> "WorkerPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
