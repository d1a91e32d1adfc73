"""Bullet physics clients: connected quietly, and reused through a pool somebody owns.

Connecting a DIRECT client costs ~25 ms of CPU (it allocates a whole physics
server); `resetSimulation` on one that is no longer used ~1.5 ms. A
`ClientPool` therefore keeps the clients its simulations closed, for the next
simulation of the same owner (a Predictor's sample worlds, a pool worker, the
shelf generator). Each client belongs to one simulation at a time; the pool's
owner closes it, and every client it ever handed out is disconnected then.
"""
from __future__ import annotations

import functools
import os
import threading

from shelfpick.perception.stdio import quiet_stdio

with quiet_stdio():   # the "pybullet build time" line goes to stderr on first import
    import pybullet
    from pybullet_utils.bullet_client import BulletClient

# BulletClient resolves every call through __getattr__ (a new partial each time);
# binding the calls a trial makes thousands of times once saves ~20% of its Python time
HOT_CALLS = ("getBasePositionAndOrientation", "getBaseVelocity", "stepSimulation", "getContactPoints",
             "changeConstraint", "resetBasePositionAndOrientation", "resetBaseVelocity",
             "applyExternalForce", "setCollisionFilterGroupMask", "performCollisionDetection",
             # once or a few times per pull, per state or per world built (~1 % of a worker's time)
             "getAABB", "saveState", "restoreState", "removeState", "getDynamicsInfo", "createConstraint",
             "removeConstraint", "setCollisionFilterPair", "changeDynamics", "createCollisionShape",
             "createMultiBody")


class Client(BulletClient):
    """A BulletClient with the hot calls bound to its physics server once."""

    def __init__(self, gui: bool = False) -> None:
        super().__init__(connection_mode=pybullet.GUI if gui else pybullet.DIRECT)
        self.gui = gui
        for name in HOT_CALLS:
            self.__dict__[name] = functools.partial(getattr(pybullet, name), physicsClientId=self._client)


def disconnect_quietly(client: Client) -> None:
    """Disconnect, whether or not the physics server is still there."""
    try:
        client.disconnect()
    except Exception:  # noqa: BLE001 - already gone
        pass


def connect(gui: bool = False) -> Client:
    """A new client whose C-level banner ("argv[0]=", build time) stays off stdout/stderr.

    `shelfpick simulate` prints JSON on stdout; pybullet's printf would corrupt it.
    """
    with quiet_stdio():
        return Client(gui)


class ClientPool:
    """DIRECT clients handed out to simulations and taken back for reuse; thread-safe."""

    def __init__(self, keep: int = 64) -> None:
        self.keep = keep
        self._idle: list[Client] = []
        self._all: list[Client] = []
        self._pid = os.getpid()
        self._lock = threading.Lock()
        self._closed = False

    def acquire(self) -> Client:
        with self._lock:
            if self._closed:
                raise RuntimeError("the client pool is closed")
            if os.getpid() != self._pid:
                raise RuntimeError("a ClientPool belongs to the process that created it")
            if self._idle:
                return self._idle.pop()
        client = connect(False)
        with self._lock:
            self._all.append(client)
        return client

    def release(self, client: Client) -> None:
        """Back to the pool, its world dropped (every body, constraint and saved state)."""
        with self._lock:
            keep = not self._closed and len(self._idle) < self.keep and os.getpid() == self._pid
        if not keep:
            self._disconnect(client)
            return
        client.resetSimulation()
        with self._lock:
            self._idle.append(client)

    def _disconnect(self, client: Client) -> None:
        with self._lock:
            if client in self._all:
                self._all.remove(client)
        disconnect_quietly(client)

    def close(self) -> None:
        with self._lock:
            self._closed = True
            clients, self._all, self._idle = self._all, [], []
        if os.getpid() != self._pid:
            return   # a copy in a child process: the clients are the parent's
        for c in clients:
            disconnect_quietly(c)

    def __enter__(self) -> "ClientPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
