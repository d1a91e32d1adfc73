"""Which console owns a run, and whether it is still alive: an OS advisory lock per open store.

A `runs` row names its console as `host:pid:token`. After a console died
mid-run (kill -9, power cut), the next console to open the database must
mark that run interrupted, but it must leave alone a run of a console that is
still going, even one in the same process (two stores opened independently
on one file).

Why a lock file and not a process-wide set of live owners: the operating
system already knows which processes are alive and which files they hold,
and it forgets a dead process's locks by itself. Each writable store holds
`fcntl.flock(LOCK_EX)` on `<db>.owners/<pid>-<token>.lock` from open to
close (or to the process's death, or to the store being garbage collected).
`flock` locks belong to an open file description, so a second store in the
same process that opens the file anew is refused the lock just like another
process would be: "locked" means "alive", wherever the owner runs. Nothing
in the database file changes; the lock files live in a folder beside it and
are removed when their store closes (or, left by a crash, when a later
console finds them unlocked).

An owner with no lock file (a console of an older shelfpick, or one that
closed its store) is judged as before: by its pid on this host; a run of our
own pid without a lock file belongs to a store already closed, so it is dead.
Another host's owner is assumed alive (flock over network file systems is
not to be trusted).
"""
from __future__ import annotations

import fcntl
import os
import socket
import weakref
from pathlib import Path

LOCK_SUFFIX = ".lock"


def owners_dir(db_path: Path) -> Path:
    """The folder beside the database that holds one lock file per open writable store."""
    return db_path.with_name(db_path.name + ".owners")


def _lock_name(owner: str) -> str | None:
    """`pid-token.lock` for `host:pid:token`; None when the owner string has another shape."""
    _host, _, rest = owner.partition(":")
    pid_s, _, token = rest.partition(":")
    if not pid_s.isdigit() or not token or not token.isalnum():
        return None
    return f"{pid_s}-{token}{LOCK_SUFFIX}"


def _release(fd: int, path: str) -> None:
    """Drop the lock file (still holding the lock, so nobody takes a file about to vanish), then the lock."""
    try:
        if os.path.exists(path) and os.stat(path).st_ino == os.fstat(fd).st_ino:
            os.unlink(path)
    except OSError:
        pass
    try:
        os.close(fd)      # closing the last descriptor releases the flock
    except OSError:
        pass


class OwnerLock:
    """The lock that says "this store's console is alive", held from open until `release()`.

    Released by `release()`, by garbage collection of the lock (a store dropped
    without close), at interpreter exit, or by the OS when the process dies.
    OSError (naming the lock file) when it cannot be created or locked.
    """

    def __init__(self, db_path: Path, owner: str) -> None:
        name = _lock_name(owner)
        if name is None:
            raise ValueError(f"owner: expected host:pid:token, got {owner!r}")
        folder = owners_dir(db_path)
        self.path = folder / name
        try:
            folder.mkdir(exist_ok=True)
            fd = self._acquire()
        except OSError as exc:
            raise OSError(f"{self.path}: cannot hold the console's lock file ({exc})") from None
        self._finalizer = weakref.finalize(self, _release, fd, str(self.path))

    def _acquire(self) -> int:
        """Create and lock the file; retry if a sweeper unlinked it between the two steps."""
        for _ in range(5):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                if os.stat(self.path).st_ino == os.fstat(fd).st_ino:
                    return fd
            except OSError:
                pass
            os.close(fd)
        raise OSError("the lock file keeps disappearing or is held by another console")

    def release(self) -> None:
        self._finalizer()


def _lock_state(path: Path) -> bool | None:
    """True: the lock file is held (its console is alive); False: it is not (a crash left it, now
    removed); None: there is no lock file."""
    try:
        fd = os.open(path, os.O_RDWR)
    except FileNotFoundError:
        return None
    except OSError:
        return True        # cannot look: do not take a possibly live run for a crash
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return True
    except OSError:
        os.close(fd)
        return True
    _release(fd, str(path))
    return False


def owner_alive(owner: str, db_path: Path) -> bool:
    """Is the console that started a run still running? (host:pid:token; another host: assume yes)."""
    host, _, rest = owner.partition(":")
    pid_s, _, _token = rest.partition(":")
    if host != socket.gethostname():
        return True
    try:
        pid = int(pid_s)
    except ValueError:
        return False
    name = _lock_name(owner)
    held = _lock_state(owners_dir(db_path) / name) if name else None
    if held is not None:
        return held
    if pid == os.getpid():
        return False       # every open store of this process holds its lock file
    return _pid_alive(pid)


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def sweep(db_path: Path) -> list[str]:
    """Remove lock files that nobody holds (left by consoles that crashed); their names."""
    folder = owners_dir(db_path)
    try:
        names = sorted(p.name for p in folder.iterdir() if p.name.endswith(LOCK_SUFFIX))
    except OSError:
        return []
    return [n for n in names if _lock_state(folder / n) is False]
