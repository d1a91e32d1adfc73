"""The session database file: its schema and migrations, opening it, and refusing files not ours.

One SQLite file in WAL mode (synchronous=FULL, foreign keys on). A file that
is not a shelfpick session log, or one written by a newer shelfpick, is
refused before anything is written to it, read-only or not; older versions
are migrated in place (1 -> 2 -> 3: tables added; 3 -> 4: columns added; `meta.schema` raised).
SQLite's errors become one-line `StoreError`s naming the file and the cause.
"""
from __future__ import annotations

import sqlite3
import time
from pathlib import Path

from shelfpick.perception.errors import ShelfpickError

SCHEMA_VERSION = 4          # 2: the runs table (crash recovery); 3: verifications (the look after each step);
                            # 4: captures.labels, captures.matter (perception's label images: the overlay redrawn)
OUR_TABLES = frozenset({"meta", "sessions", "captures", "scenes", "plans", "decisions", "robot_events", "outcomes",
                        "runs", "verifications"})

ADDED_COLUMNS = {"captures": ("labels", "matter")}    # by a migration to an existing table (TEXT)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS sessions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    started TEXT NOT NULL,
    source TEXT NOT NULL,
    n_boxes INTEGER NOT NULL,
    status TEXT NOT NULL,
    task TEXT,
    files TEXT
);
CREATE TABLE IF NOT EXISTS captures (
    session_id INTEGER PRIMARY KEY REFERENCES sessions(id),
    rgb TEXT NOT NULL, depth TEXT, camera TEXT NOT NULL, masks TEXT, masks_json TEXT, overlay TEXT,
    width INTEGER NOT NULL, height INTEGER NOT NULL,
    labels TEXT, matter TEXT         -- perceived masks, unexplained regions (uint16 PNG, schema 4)
);
CREATE TABLE IF NOT EXISTS scenes (
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    kind TEXT NOT NULL,              -- 'perceived' | 'truth'
    scene TEXT NOT NULL,             -- shelfpick.scene/1 JSON
    perception TEXT,                 -- warnings, timing (perceived only)
    PRIMARY KEY (session_id, kind)
);
CREATE TABLE IF NOT EXISTS plans (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    created TEXT NOT NULL,
    hash TEXT NOT NULL,
    planner TEXT NOT NULL,
    task TEXT NOT NULL,
    target TEXT,
    plan TEXT NOT NULL,              -- shelfpick.plan/1 JSON
    preview TEXT                     -- preview frames JSON (optional)
);
CREATE TABLE IF NOT EXISTS decisions (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    plan_hash TEXT NOT NULL,
    decision TEXT NOT NULL CHECK (decision IN ('approve', 'reject')),
    who TEXT NOT NULL,
    at TEXT NOT NULL,
    reason TEXT
);
CREATE TABLE IF NOT EXISTS robot_events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    plan_hash TEXT NOT NULL,
    at TEXT NOT NULL,
    kind TEXT NOT NULL,
    step INTEGER,
    box TEXT,
    detail TEXT
);
CREATE TABLE IF NOT EXISTS outcomes (
    session_id INTEGER PRIMARY KEY REFERENCES sessions(id),
    at TEXT NOT NULL,
    outcome TEXT NOT NULL
);
CREATE TABLE IF NOT EXISTS runs (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    plan_hash TEXT NOT NULL,
    decision_id INTEGER REFERENCES decisions(id),
    owner TEXT NOT NULL,             -- host:pid:token of the console that runs it
    started TEXT NOT NULL,
    ended TEXT,
    result TEXT                      -- done | stopped | failed | interrupted
);
CREATE TABLE IF NOT EXISTS verifications (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    session_id INTEGER NOT NULL REFERENCES sessions(id),
    plan_hash TEXT NOT NULL,
    run TEXT,                        -- the robot run id of the step's run
    at TEXT NOT NULL,
    step INTEGER NOT NULL,
    box TEXT,
    within INTEGER NOT NULL,         -- 1: the next step may go, 0: the robot was held
    verdict TEXT NOT NULL,           -- console.workflow.verify.Verification JSON (matches, distances, timing)
    predicted TEXT,                  -- shelfpick.scene/1: the shelf the plan predicted after the step
    observed TEXT                    -- shelfpick.scene/1: the shelf perceived after the step
);
CREATE INDEX IF NOT EXISTS plans_session ON plans(session_id);
CREATE INDEX IF NOT EXISTS verifications_session ON verifications(session_id);
CREATE INDEX IF NOT EXISTS decisions_session ON decisions(session_id);
CREATE INDEX IF NOT EXISTS events_session ON robot_events(session_id);
"""


class StoreError(ShelfpickError):
    """The session database cannot be opened or written (locked, read-only, full, corrupt)."""


class RunConflict(StoreError):
    """A run is already going on this database (another console's, or this one's): one run at a time."""


def explain(exc: sqlite3.Error, path: Path) -> str:
    """One line for an SQLite error: the file, what went wrong, what to do."""
    msg = str(exc)
    low = msg.lower()
    if "locked" in low or "busy" in low:
        return (f"{path}: database is locked by another process or connection ({msg}); "
                f"close the other program or use another --db")
    if "readonly" in low or "read-only" in low or "unable to open" in low or "permission" in low:
        return (f"{path}: database cannot be written ({msg}); check the file and folder "
                f"permissions or use another --db")
    if "full" in low:
        return (f"{path}: database or disk is full ({msg}); free space or use another --db; "
                f"nothing was recorded")
    if "not a database" in low or "malformed" in low:
        return f"{path}: not a shelfpick session database or corrupt ({msg})"
    return f"{path}: database error ({exc.__class__.__name__}: {msg})"


def open_readonly(path: Path) -> sqlite3.Connection:
    """A connection that cannot write; refuses a file that is not a shelfpick session log."""
    if not path.is_file():
        raise StoreError(f"{path}: no session database here (pass --db PATH)")
    db = None
    last: sqlite3.Error | None = None
    # mode=ro reads the WAL too; immutable=1 for a folder where not even the -shm can be made.
    # No -wal/-shm beside the file: no console has it open and every commit is in the file, so it is
    # read as immutable: a mode=ro reader would create -wal/-shm it cannot remove, left beside an archive
    side = [path.with_name(path.name + s) for s in ("-wal", "-shm")]
    queries = ("mode=ro&immutable=1",) if not any(p.exists() for p in side) else ("mode=ro", "mode=ro&immutable=1")
    for query in queries:
        try:
            db = sqlite3.connect(f"{path.resolve().as_uri()}?{query}", uri=True,
                                 isolation_level=None, check_same_thread=False)
            db.row_factory = sqlite3.Row
            tables = {r[0] for r in db.execute("SELECT name FROM sqlite_master WHERE type='table'")}
            break
        except sqlite3.Error as exc:
            last = exc
            if db is not None:
                db.close()
            db = None
    if db is None:
        raise StoreError(explain(last, path)) from None  # type: ignore[arg-type]
    _check_ours(db, tables, path)
    return db


def _check_ours(db: sqlite3.Connection, tables: set[str], path: Path) -> None:
    """Close `db` and raise StoreError unless it is a shelfpick session log this version can read."""
    version = None
    if "meta" in tables:
        row = db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
        version = row[0] if row else None
    if version is None or not {"sessions", "decisions", "robot_events"} <= tables:
        db.close()
        other = ", ".join(sorted(tables - OUR_TABLES)[:5]) or "none of ours"
        raise StoreError(f"{path}: not a shelfpick session database (tables: {other}); "
                         f"nothing was written to it; pass another --db")
    if not str(version).isdigit() or int(version) > SCHEMA_VERSION:
        db.close()
        raise StoreError(f"{path}: meta.schema: session database version {version!r} is newer "
                         f"than this shelfpick ({SCHEMA_VERSION}); use a newer shelfpick")


def open_writable(path: Path, timeout: float, max_pages: int | None) -> sqlite3.Connection:
    """Open (creating it and its folder) the session log for writing, migrated to SCHEMA_VERSION."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise StoreError(f"{path}: cannot create the database folder ({exc})") from None
    if path.exists() and not path.stat().st_mode & 0o222:
        # honour a file marked read-only even when running as root (root ignores modes)
        raise StoreError(f"{path}: database cannot be written (file is read-only, mode "
                         f"{path.stat().st_mode & 0o777:o}); make it writable or use another --db")
    if path.exists() and path.stat().st_size > 0:
        ours_or_being_made(path, timeout)      # ours? (refused before anything is written to it)
    try:
        db = sqlite3.connect(str(path), timeout=timeout, isolation_level=None, check_same_thread=False)
        db.row_factory = sqlite3.Row
        mode = to_wal(db, timeout)
        if str(mode).lower() != "wal":
            raise sqlite3.OperationalError(f"cannot switch to WAL mode (journal_mode={mode}), "
                                           f"read-only or unsupported file system")
        db.execute("PRAGMA synchronous=FULL")
        db.execute("PRAGMA foreign_keys=ON")
        db.execute(f"PRAGMA busy_timeout={int(timeout * 1000)}")
        create_schema(db)
        if max_pages is not None:
            db.execute(f"PRAGMA max_page_count={int(max_pages)}")
    except sqlite3.Error as exc:
        raise StoreError(explain(exc, path)) from None
    return db


SQLITE_HEADER = b"SQLite format 3\x00"


def to_wal(db: sqlite3.Connection, timeout: float) -> str:
    """PRAGMA journal_mode=WAL; the journal mode it gives. SQLite answers "locked" at once, without
    its busy wait, while another connection switches the same new file too: tried again until
    `timeout` s (two consoles started at once on a new --db)."""
    end = time.monotonic() + max(timeout, 1.0)
    while True:
        try:
            return str(db.execute("PRAGMA journal_mode=WAL").fetchone()[0])
        except sqlite3.OperationalError as exc:
            if "locked" not in str(exc).lower() or time.monotonic() >= end:
                raise
        time.sleep(0.02)


def ours_or_being_made(path: Path, timeout: float) -> None:
    """`open_readonly`'s check, looked at again for up to `timeout` s while the file is an SQLite
    file with no table yet: another console creating this log at the same moment (two consoles
    started at once on a new --db) has made the file and not yet committed its schema. Anything
    else that is not ours is refused at once."""
    end = time.monotonic() + max(timeout, 1.0)
    while True:
        try:
            open_readonly(path).close()
            return
        except StoreError:
            if time.monotonic() >= end:
                raise
            if not _no_table_yet(path):    # tables now (committed since that look) or not SQLite:
                open_readonly(path).close()  # one more look decides
                return
        time.sleep(0.02)


def _no_table_yet(path: Path) -> bool:
    """An SQLite file with no table in it (or not readable yet, mid-creation); False for anything else."""
    try:
        with path.open("rb") as f:
            if f.read(len(SQLITE_HEADER)) != SQLITE_HEADER:
                return False
    except OSError:
        return False
    try:
        db = sqlite3.connect(f"{path.resolve().as_uri()}?mode=ro", uri=True, timeout=0.1)
        try:
            return db.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()[0] == 0
        finally:
            db.close()
    except sqlite3.Error:
        return True


def create_schema(db: sqlite3.Connection) -> None:
    """Create the tables a new or older log lacks and raise `meta.schema`, in one transaction."""
    cur = db.cursor()
    try:
        cur.execute("BEGIN IMMEDIATE")
        for stmt in _SCHEMA.split(";"):
            if stmt.strip():
                cur.execute(stmt)
        have = {r[1] for r in cur.execute("PRAGMA table_info(captures)")}
        for column in ADDED_COLUMNS["captures"]:      # 3 -> 4: a log made before they were
            if column not in have:
                cur.execute(f"ALTER TABLE captures ADD COLUMN {column} TEXT")
        cur.execute("INSERT OR IGNORE INTO meta(key, value) VALUES ('schema', ?)",
                    (str(SCHEMA_VERSION),))
        cur.execute("UPDATE meta SET value=? WHERE key='schema' AND CAST(value AS INTEGER) < ?",
                    (str(SCHEMA_VERSION), SCHEMA_VERSION))   # 1 -> 2 -> 3 -> 4: added above
        cur.execute("COMMIT")
    except BaseException:
        if db.in_transaction:
            db.execute("ROLLBACK")
        raise
