"""The console's session log: one SQLite file in WAL mode, images as PNG files beside it.

Every operator and supervisor action is a row committed at once (WAL,
synchronous=FULL), so killing the server loses no record that was already
reported as written. Images would bloat the database and make it hard to
look at, so they live in `<db>.files/<session id>/` (rgb.png, depth.png,
camera.json, masks.png, masks.json, overlay.png) and the rows hold paths
relative to the database's folder.

viser runs callbacks on a thread pool, so one connection is shared behind a
lock (`check_same_thread=False`). A database that is locked by another
process, full or cannot be written raises `StoreError` with the path and the
cause; the workflow then refuses what needed the record (audit first).

`readonly=True` (`shelfpick sessions`, `shelfpick replay`) never writes: a
read-only archive lists and replays. A SQLite file that is not a shelfpick
session log is refused in either mode before anything is written to it.
The `runs` table says which console runs which plan: after a console died
mid-run (kill -9), `recover_interrupted` marks the run interrupted and the
acknowledged step unknown; `step_states` is "never re-send a step", keyed by
session (one capture) and plan hash.
"""
from __future__ import annotations

import json
import shutil
import sqlite3
import threading
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any, Iterator

import numpy as np

from perception.capture import Capture
from perception.errors import ShelfpickError
from perception.scene import Scene
from planning.plan import Plan

DEFAULT_DB = Path("data") / "shelfpick.db"
SCHEMA_VERSION = 3          # 2: the runs table (crash recovery); 3: verifications (the look after each step)
OUR_TABLES = frozenset({"meta", "sessions", "captures", "scenes", "plans", "decisions", "robot_events", "outcomes",
                        "runs", "verifications"})
ROBOT_KINDS = ("start", "ack", "done", "error", "aborted", "disconnected", "unknown")

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
    width INTEGER NOT NULL, height INTEGER NOT NULL
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
    verdict TEXT NOT NULL,           -- console.verify.Verification JSON (matches, distances, timing)
    predicted TEXT,                  -- shelfpick.scene/1: the shelf the plan predicted after the step
    observed TEXT                    -- shelfpick.scene/1: the shelf perceived after the step
);
CREATE INDEX IF NOT EXISTS plans_session ON plans(session_id);
CREATE INDEX IF NOT EXISTS verifications_session ON verifications(session_id);
CREATE INDEX IF NOT EXISTS decisions_session ON decisions(session_id);
CREATE INDEX IF NOT EXISTS events_session ON robot_events(session_id);
"""


def stored_scene(text: str | None, origin: str = "") -> Scene | None:
    """A verification's stored shelf; a predicted box out of the shelf's bounds (stored by an
    older console: a box predicted to fall) is kept, so the record still replays."""
    if not text:
        return None
    from perception.errors import FormatError
    from perception.scene import Box, Shelf

    doc = json.loads(text)
    try:
        return Scene.from_json(doc, origin)
    except FormatError:
        if not isinstance(doc, dict) or not isinstance(doc.get("boxes"), list):
            raise
        return Scene(Shelf.from_json(doc["shelf"], origin),
                     tuple(Box.from_json(b, origin, f"boxes[{i}]") for i, b in enumerate(doc["boxes"])))


class StoreError(ShelfpickError):
    """The session database cannot be opened or written (locked, read-only, full, corrupt)."""


# the consoles of this process that hold a store open: their runs are alive, whatever the pid says
_LIVE_OWNERS: set[str] = set()
_OWNERS_LOCK = threading.Lock()


def _owner_alive(owner: str) -> bool:
    """Is the console that started a run still running? (host:pid:token; another host: assume yes)."""
    import os
    import socket

    host, _, rest = owner.partition(":")
    pid_s, _, _token = rest.partition(":")
    if host != socket.gethostname():
        return True
    try:
        pid = int(pid_s)
    except ValueError:
        return False
    if pid == os.getpid():
        with _OWNERS_LOCK:
            return owner in _LIVE_OWNERS
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def utc_now() -> str:
    """UTC time, ISO 8601 with milliseconds: sortable and unambiguous across machines."""
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


@dataclass(frozen=True)
class PlanRecord:
    hash: str
    plan: Plan
    created: str
    preview: list | None = None


@dataclass(frozen=True, eq=False)
class SessionRecord:
    """Everything stored for one session, images loaded back as numpy arrays."""

    id: int
    started: str
    source: str
    status: str
    task: str | None
    capture: Capture | None
    overlay: np.ndarray | None
    scene: Scene
    truth: Scene | None
    perception: dict | None
    plans: tuple[PlanRecord, ...] = ()
    decisions: tuple[dict, ...] = ()
    robot_events: tuple[dict, ...] = ()
    outcome: dict | None = None
    verifications: tuple[dict, ...] = ()   # per verified step: verdict, predicted and observed Scene
    files: Path | None = None
    missing_files: tuple[str, ...] = field(default_factory=tuple)

    def plan(self, plan_hash: str) -> Plan:
        for p in self.plans:
            if p.hash == plan_hash:
                return p.plan
        raise KeyError(plan_hash)

    @property
    def n_boxes(self) -> int:
        return len(self.scene.boxes)


def _explain(exc: sqlite3.Error, path: Path) -> str:
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


class SessionStore:
    """The session log of one console (thread safe; every write committed at once)."""

    def __init__(self, path: str | Path, *, timeout: float = 5.0, readonly: bool = False,
                 max_pages: int | None = None) -> None:
        """Open (and, for writing, create) the session log at `path`.

        `readonly`: list and load only, nothing is written (an archive on a
        read-only disk, `shelfpick sessions`, `shelfpick replay`); the file
        must exist. A SQLite file that is not a shelfpick session log is
        refused either way, before anything is written to it. `max_pages`
        caps the database size in pages (a quota; a write beyond it fails
        as on a full disk).
        """
        import os
        import secrets
        import socket

        self.path = Path(path)
        self.files_root = self.path.with_name(self.path.name + ".files")
        self.readonly = bool(readonly)
        self._lock = threading.RLock()
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(4)}"
        if self.path.exists() and self.path.is_dir():
            raise StoreError(f"{self.path}: is a folder, expected a database file")
        if self.readonly:
            self._db = self._open_readonly()
            return
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"{self.path}: cannot create the database folder ({exc})") from None
        if self.path.exists() and not self.path.stat().st_mode & 0o222:
            # honour a file marked read-only even when running as root (root ignores modes)
            raise StoreError(f"{self.path}: database cannot be written (file is read-only, mode "
                             f"{self.path.stat().st_mode & 0o777:o}); make it writable or use another --db")
        if self.path.exists() and self.path.stat().st_size > 0:
            self._open_readonly().close()      # ours? (refused before anything is written to it)
        try:
            self._db = sqlite3.connect(str(self.path), timeout=timeout, isolation_level=None,
                                       check_same_thread=False)
            self._db.row_factory = sqlite3.Row
            mode = self._db.execute("PRAGMA journal_mode=WAL").fetchone()[0]
            if str(mode).lower() != "wal":
                raise sqlite3.OperationalError(f"cannot switch to WAL mode (journal_mode={mode}), "
                                               f"read-only or unsupported file system")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.execute("PRAGMA foreign_keys=ON")
            self._db.execute(f"PRAGMA busy_timeout={int(timeout * 1000)}")
            self._create_schema()
            if max_pages is not None:
                self._db.execute(f"PRAGMA max_page_count={int(max_pages)}")
        except sqlite3.Error as exc:
            raise StoreError(_explain(exc, self.path)) from None
        with _OWNERS_LOCK:
            _LIVE_OWNERS.add(self.owner)

    def _open_readonly(self) -> sqlite3.Connection:
        """A connection that cannot write; refuses a file that is not a shelfpick session log."""
        if not self.path.is_file():
            raise StoreError(f"{self.path}: no session database here (pass --db PATH)")
        db = None
        last: sqlite3.Error | None = None
        # mode=ro reads the WAL too; immutable=1 for a folder where not even the -shm can be made
        for query in ("mode=ro", "mode=ro&immutable=1"):
            try:
                db = sqlite3.connect(f"{self.path.resolve().as_uri()}?{query}", uri=True,
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
            raise StoreError(_explain(last, self.path)) from None  # type: ignore[arg-type]
        version = None
        if "meta" in tables:
            row = db.execute("SELECT value FROM meta WHERE key='schema'").fetchone()
            version = row[0] if row else None
        if version is None or not {"sessions", "decisions", "robot_events"} <= tables:
            db.close()
            other = ", ".join(sorted(tables - OUR_TABLES)[:5]) or "none of ours"
            raise StoreError(f"{self.path}: not a shelfpick session database (tables: {other}); "
                             f"nothing was written to it; pass another --db")
        if not str(version).isdigit() or int(version) > SCHEMA_VERSION:
            db.close()
            raise StoreError(f"{self.path}: meta.schema: session database version {version!r} is newer "
                             f"than this shelfpick ({SCHEMA_VERSION}); use a newer shelfpick")
        return db

    # ------------------------------------------------------------------ plumbing
    def _create_schema(self) -> None:
        with self._lock:
            cur = self._db.cursor()
            try:
                cur.execute("BEGIN IMMEDIATE")
                for stmt in _SCHEMA.split(";"):
                    if stmt.strip():
                        cur.execute(stmt)
                cur.execute("INSERT OR IGNORE INTO meta(key, value) VALUES ('schema', ?)",
                            (str(SCHEMA_VERSION),))
                cur.execute("UPDATE meta SET value=? WHERE key='schema' AND CAST(value AS INTEGER) < ?",
                            (str(SCHEMA_VERSION), SCHEMA_VERSION))   # 1 -> 2 -> 3: tables added above
                cur.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise

    def _write(self, fn) -> Any:
        """Run fn(cursor) inside BEGIN IMMEDIATE ... COMMIT under the lock; map errors."""
        if self.readonly:
            raise StoreError(f"{self.path}: opened read-only, nothing can be recorded")
        with self._lock:
            try:
                cur = self._db.cursor()
                cur.execute("BEGIN IMMEDIATE")
                try:
                    result = fn(cur)
                    cur.execute("COMMIT")
                except BaseException:
                    if self._db.in_transaction:
                        self._db.execute("ROLLBACK")
                    raise
                return result
            except sqlite3.Error as exc:
                raise StoreError(_explain(exc, self.path)) from None

    def _read(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        with self._lock:
            try:
                return self._db.execute(sql, args).fetchall()
            except sqlite3.Error as exc:
                raise StoreError(_explain(exc, self.path)) from None

    def _require_session(self, cur: sqlite3.Cursor, session_id: int) -> None:
        if cur.execute("SELECT 1 FROM sessions WHERE id=?", (session_id,)).fetchone() is None:
            raise StoreError(f"{self.path}: no session with id {session_id}")

    def journal_mode(self) -> str:
        return str(self._read("PRAGMA journal_mode")[0][0]).lower()

    def close(self) -> None:
        with _OWNERS_LOCK:
            _LIVE_OWNERS.discard(self.owner)
        with self._lock:
            try:
                self._db.close()
            except sqlite3.Error:
                pass

    def __enter__(self) -> "SessionStore":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # ------------------------------------------------------------------ writes
    def new_session(self, source: str, capture: Capture, scene: Scene, truth: Scene | None,
                    overlay: np.ndarray | None, perception: dict | None = None) -> int:
        """Record a capture and its perceived (and, when known, true) scene; returns the id.

        The row and the image files are written in one transaction: if the
        files cannot be written the row is rolled back and StoreError names
        the folder.
        """
        started = utc_now()

        def fn(cur: sqlite3.Cursor) -> int:
            cur.execute("INSERT INTO sessions(started, source, n_boxes, status) VALUES (?,?,?,?)",
                        (started, source, len(scene.boxes), "captured"))
            sid = int(cur.lastrowid)
            rel = self._save_images(sid, capture, overlay)
            cur.execute("UPDATE sessions SET files=? WHERE id=?", (f"{self.files_root.name}/{sid}", sid))
            h, w = capture.shape
            cur.execute("INSERT INTO captures(session_id, rgb, depth, camera, masks, masks_json, overlay, "
                        "width, height) VALUES (?,?,?,?,?,?,?,?,?)",
                        (sid, rel["rgb"], rel.get("depth"), rel["camera"], rel.get("masks"),
                         rel.get("masks_json"), rel.get("overlay"), w, h))
            cur.execute("INSERT INTO scenes(session_id, kind, scene, perception) VALUES (?,?,?,?)",
                        (sid, "perceived", json.dumps(scene.to_json()),
                         json.dumps(perception) if perception is not None else None))
            if truth is not None:
                cur.execute("INSERT INTO scenes(session_id, kind, scene) VALUES (?,?,?)",
                            (sid, "truth", json.dumps(truth.to_json())))
            return sid

        return self._write(fn)

    def _save_images(self, sid: int, capture: Capture, overlay: np.ndarray | None) -> dict[str, str]:
        import cv2

        d = self.files_root / str(sid)
        try:
            if d.exists():  # left over from a rolled-back attempt with the same id
                shutil.rmtree(d)
            paths = capture.save(d)
            if overlay is not None:
                ov = np.asarray(overlay)
                if ov.ndim == 3 and ov.shape[2] == 4:
                    ov = ov[:, :, :3]
                paths["overlay"] = d / "overlay.png"
                if not cv2.imwrite(str(paths["overlay"]), cv2.cvtColor(ov.astype(np.uint8), cv2.COLOR_RGB2BGR)):
                    raise OSError(f"cannot write {paths['overlay']}")
            for k, p in paths.items():
                if not Path(p).is_file():
                    raise OSError(f"cannot write {p}")
        except OSError as exc:
            raise StoreError(f"{d}: cannot save the capture images ({exc})") from None
        base = self.path.parent
        return {k: str(Path(p).relative_to(base)) for k, p in paths.items()}

    def add_plan(self, session_id: int, plan: Plan, preview: list | None = None) -> str:
        """Store a plan with its predictions (and optional preview frames); returns its hash."""
        h = plan.content_hash()

        def fn(cur: sqlite3.Cursor) -> str:
            self._require_session(cur, session_id)
            cur.execute("INSERT INTO plans(session_id, created, hash, planner, task, target, plan, preview) "
                        "VALUES (?,?,?,?,?,?,?,?)",
                        (session_id, utc_now(), h, plan.planner, plan.task, plan.target,
                         json.dumps(plan.to_json()), json.dumps(preview) if preview is not None else None))
            task = plan.task if plan.target is None else f"{plan.task} {plan.target}"
            cur.execute("UPDATE sessions SET task=?, status=? WHERE id=?", (task, "planned", session_id))
            return h

        return self._write(fn)

    def add_decision(self, session_id: int, plan_hash: str, decision: str, who: str,
                     reason: str | None = None) -> int:
        """Record a supervisor's approve/reject of one plan (by content hash)."""
        if decision not in ("approve", "reject"):
            raise StoreError(f"decision: expected 'approve' or 'reject', got {decision!r}")

        def fn(cur: sqlite3.Cursor) -> int:
            self._require_session(cur, session_id)
            cur.execute("INSERT INTO decisions(session_id, plan_hash, decision, who, at, reason) "
                        "VALUES (?,?,?,?,?,?)", (session_id, plan_hash, decision, who, utc_now(), reason))
            did = int(cur.lastrowid)
            cur.execute("UPDATE sessions SET status=? WHERE id=?",
                        ("approved" if decision == "approve" else "rejected", session_id))
            return did

        return self._write(fn)

    def add_robot_event(self, session_id: int, plan_hash: str, kind: str, step: int | None = None,
                        box: str | None = None, detail: dict | None = None) -> int:
        """One robot event (or `auth_refused`, `stop`); robot kinds mark the session executing."""
        def fn(cur: sqlite3.Cursor) -> int:
            self._require_session(cur, session_id)
            return self._insert_event(cur, session_id, plan_hash, kind, step, box, detail)

        return self._write(fn)

    def _insert_event(self, cur: sqlite3.Cursor, session_id: int, plan_hash: str, kind: str,
                      step: int | None, box: str | None, detail: dict | None) -> int:
        cur.execute("INSERT INTO robot_events(session_id, plan_hash, at, kind, step, box, detail) "
                    "VALUES (?,?,?,?,?,?,?)",
                    (session_id, plan_hash, utc_now(), kind, step, box,
                     json.dumps(detail, default=_jsonable) if detail is not None else None))
        eid = int(cur.lastrowid)
        if kind in ROBOT_KINDS:
            cur.execute("UPDATE sessions SET status='executing' WHERE id=? AND status NOT IN "
                        "('done', 'failed', 'stopped', 'interrupted')", (session_id,))
        return eid

    def start_run(self, session_id: int, plan_hash: str, decision_id: int | None, detail: dict) -> int:
        """Commit that this console starts running an approved plan (before the robot moves).

        The `start` event and the run row go in one transaction; the run row
        says which console owns the run, so that a restart can tell a run
        that died with its console (kill -9, power) from one still going.
        """
        def fn(cur: sqlite3.Cursor) -> int:
            self._require_session(cur, session_id)
            open_run = cur.execute("SELECT id FROM runs WHERE session_id=? AND ended IS NULL",
                                   (session_id,)).fetchone()
            if open_run is not None:
                raise StoreError(f"{self.path}: session {session_id} already has a run in progress "
                                 f"(run {open_run[0]})")
            cur.execute("INSERT INTO runs(session_id, plan_hash, decision_id, owner, started) VALUES (?,?,?,?,?)",
                        (session_id, plan_hash, decision_id, self.owner, utc_now()))
            rid = int(cur.lastrowid)
            self._insert_event(cur, session_id, plan_hash, "start", None, None, {**detail, "run": rid})
            return rid

        return self._write(fn)

    def add_verification(self, session_id: int, plan_hash: str, run: str | None, verdict: dict,
                         predicted: Scene | None, observed: Scene | None) -> int:
        """The look after one step: the verdict, the predicted and the observed shelf (before the next step)."""
        def fn(cur: sqlite3.Cursor) -> int:
            self._require_session(cur, session_id)
            cur.execute("INSERT INTO verifications(session_id, plan_hash, run, at, step, box, within, verdict, "
                        "predicted, observed) VALUES (?,?,?,?,?,?,?,?,?,?)",
                        (session_id, plan_hash, run, utc_now(), int(verdict["step"]), verdict.get("box"),
                         1 if verdict.get("within") else 0, json.dumps(verdict, default=_jsonable),
                         json.dumps(predicted.to_json()) if predicted is not None else None,
                         json.dumps(observed.to_json()) if observed is not None else None))
            return int(cur.lastrowid)

        return self._write(fn)

    def verification_stats(self) -> list[dict]:
        """Every verified step of every session: plan hash, step, within, and the plan's predicted risk."""
        if not self._has_table("verifications"):
            return []
        rows = self._read("SELECT v.session_id, v.plan_hash, v.step, v.box, v.within, v.verdict, "
                          "(SELECT p.plan FROM plans p WHERE p.session_id=v.session_id AND p.hash=v.plan_hash "
                          "ORDER BY p.id DESC LIMIT 1) AS plan FROM verifications v ORDER BY v.id")
        out = []
        for r in rows:
            plan = json.loads(r["plan"]) if r["plan"] else {}
            pred = plan.get("predicted") or []
            step = int(r["step"])
            p = pred[step] if step < len(pred) and isinstance(pred[step], dict) else {}
            out.append({"session": r["session_id"], "plan": r["plan_hash"], "planner": plan.get("planner"),
                        "step": step, "box": r["box"], "within": bool(r["within"]),
                        "collapse_prob": float(p.get("collapse_prob", 0.0) or 0.0),
                        "collision_prob": float(p.get("collision_prob", 0.0) or 0.0),
                        "verdict": json.loads(r["verdict"])})
        return out

    def step_stats(self) -> list[dict]:
        """Every step a robot reported done, in every session: the plan's predicted risk for it,
        whether the robot reported boxes collapsing, and the look after it (None: not verified)."""
        rows = self._read("SELECT e.session_id, e.plan_hash, e.kind, e.step, e.box, e.detail, "
                          "(SELECT p.plan FROM plans p WHERE p.session_id=e.session_id AND p.hash=e.plan_hash "
                          "ORDER BY p.id DESC LIMIT 1) AS plan FROM robot_events e "
                          "WHERE e.kind IN ('done', 'error') AND e.step IS NOT NULL ORDER BY e.id")
        looks = {(v["session"], v["plan"], v["step"]): v for v in self.verification_stats()}
        out: dict[tuple, dict] = {}
        for r in rows:
            key = (r["session_id"], r["plan_hash"], int(r["step"]))
            detail = json.loads(r["detail"]) if r["detail"] else {}
            collapsed = bool(detail.get("collapsed")) or detail.get("code") == "COLLAPSE"
            if r["kind"] == "error":
                if key in out and collapsed:
                    out[key]["robot_collapse"] = True
                continue
            plan = json.loads(r["plan"]) if r["plan"] else {}
            pred = plan.get("predicted") or []
            p = pred[key[2]] if key[2] < len(pred) and isinstance(pred[key[2]], dict) else {}
            look = looks.get(key)
            verdict = look["verdict"] if look else None
            out[key] = {"session": key[0], "plan": key[1], "planner": plan.get("planner"), "step": key[2],
                        "box": r["box"], "collapse_prob": float(p.get("collapse_prob", 0.0) or 0.0),
                        "robot_collapse": collapsed,
                        "verified": None if look is None else (
                            "unavailable" if verdict.get("unavailable") else
                            "within" if look["within"] else "deviation")}
        return list(out.values())

    def _has_table(self, name: str) -> bool:
        return bool(self._read("SELECT 1 FROM sqlite_master WHERE type='table' AND name=?", (name,)))

    def set_outcome(self, session_id: int, outcome: dict, run_id: int | None = None) -> None:
        """The run's outcome; the session's status says done, held, stopped, interrupted or failed."""
        ok = bool(outcome.get("ok"))
        status = ("done" if ok else "interrupted" if outcome.get("interrupted")
                  else "stopped" if outcome.get("stopped") else "held" if outcome.get("held") else "failed")

        def fn(cur: sqlite3.Cursor) -> None:
            self._require_session(cur, session_id)
            cur.execute("INSERT OR REPLACE INTO outcomes(session_id, at, outcome) VALUES (?,?,?)",
                        (session_id, utc_now(), json.dumps(outcome, default=_jsonable)))
            cur.execute("UPDATE sessions SET status=? WHERE id=?", (status, session_id))
            if run_id is not None:
                cur.execute("UPDATE runs SET ended=?, result=? WHERE id=?", (utc_now(), status, run_id))

        self._write(fn)

    def step_states(self, session_id: int, plan_hash: str) -> dict[int, tuple[str, str | None]]:
        """step -> (state, box) from the robot events of this session's runs of this plan.

        state: `in_flight` (acknowledged, not finished), `done`, `failed`,
        `aborted` or `unknown` (in flight when the link or the console died).
        This is what "never re-send a step" is keyed by: session (one capture)
        and plan, stored, so it holds after a restart.
        """
        rows = self._read("SELECT kind, step, box, detail FROM robot_events WHERE session_id=? AND "
                          "plan_hash=? AND step IS NOT NULL ORDER BY id", (session_id, plan_hash))
        out: dict[int, tuple[str, str | None]] = {}
        for r in rows:
            kind, step = r["kind"], int(r["step"])
            prev = out.get(step, ("", None))[0]
            if kind == "ack":
                state = "in_flight"
            elif kind == "done":
                state = "done"
            elif kind == "error":
                state = "failed" if prev != "done" else "done"
            elif kind == "aborted":
                unconfirmed = "unconfirmed" in (json.loads(r["detail"]) if r["detail"] else {})
                state = "unknown" if unconfirmed and prev != "done" else (prev if prev == "done" else "aborted")
            elif kind in ("disconnected", "unknown"):
                state = "unknown" if prev != "done" else "done"
            else:
                continue
            out[step] = (state, r["box"])
        return out

    def recover_interrupted(self) -> list[dict]:
        """Runs whose console died (kill -9, power cut) while executing: mark them interrupted.

        The step that was acknowledged but not finished gets an `unknown`
        event (the robot may have moved it or not); the session gets an
        outcome saying so and the status `interrupted`. Runs of a console that
        is still alive are left alone. Returns one dict per recovered run.
        """
        if self.readonly:
            return []
        runs = self._read("SELECT * FROM runs WHERE ended IS NULL ORDER BY id")
        found = []
        for run in runs:
            if _owner_alive(run["owner"]):
                continue
            found.append(self._interrupt(run))
        return found

    def _interrupt(self, run: sqlite3.Row) -> dict:
        sid, h = int(run["session_id"]), run["plan_hash"]
        states = self.step_states(sid, h)
        plan_row = self._read("SELECT plan FROM plans WHERE session_id=? AND hash=? ORDER BY id DESC LIMIT 1",
                              (sid, h))
        sequence = json.loads(plan_row[0]["plan"]).get("sequence", []) if plan_row else []
        reason = "the console stopped (crash or kill) while this step was in flight; its outcome is unknown"
        unknown = [(i, box) for i, (st, box) in sorted(states.items()) if st == "in_flight"]
        steps = []
        for i, box in enumerate(sequence):
            st = states.get(i, ("not_sent", box))[0]
            steps.append({"step": i, "box": box, "status": "unknown" if st == "in_flight" else st,
                          "detail": {"reason": reason} if st == "in_flight" else {}})
        done = [box for i, box in enumerate(sequence) if states.get(i, ("",))[0] == "done"]
        err = "the console stopped during execution (crash or kill)" + (
            "; step " + ", ".join(f"{i + 1} ({b})" for i, b in unknown) + ": outcome unknown" if unknown else "")
        outcome = {"plan": h, "sequence": sequence, "completed": done, "ok": False, "stopped": False,
                   "interrupted": True, "error": err, "steps": steps}

        def fn(cur: sqlite3.Cursor) -> None:
            for i, box in unknown:
                self._insert_event(cur, sid, h, "unknown", i, box, {"reason": reason})
            cur.execute("INSERT OR IGNORE INTO outcomes(session_id, at, outcome) VALUES (?,?,?)",
                        (sid, utc_now(), json.dumps(outcome)))
            cur.execute("UPDATE sessions SET status='interrupted' WHERE id=?", (sid,))
            cur.execute("UPDATE runs SET ended=?, result='interrupted' WHERE id=?", (utc_now(), run["id"]))

        self._write(fn)
        return {"session": sid, "plan": h, "unknown": unknown, "completed": done}

    # ------------------------------------------------------------------ reads
    def list_sessions(self) -> list[dict]:
        """Newest first: id, started, source, n_boxes, task, status (plus plan/decision counts)."""
        rows = self._read(
            "SELECT s.id, s.started, s.source, s.n_boxes, s.task, s.status, "
            "(SELECT COUNT(*) FROM plans p WHERE p.session_id=s.id) AS n_plans, "
            "(SELECT COUNT(*) FROM decisions d WHERE d.session_id=s.id) AS n_decisions "
            "FROM sessions s ORDER BY s.id DESC")
        return [dict(r) for r in rows]

    def load_session(self, session_id: int) -> SessionRecord:
        with self._lock:
            srow = self._read("SELECT * FROM sessions WHERE id=?", (session_id,))
            if not srow:
                raise StoreError(f"{self.path}: no session with id {session_id}")
            s = srow[0]
            crow = self._read("SELECT * FROM captures WHERE session_id=?", (session_id,))
            scenes = {r["kind"]: r for r in self._read("SELECT * FROM scenes WHERE session_id=?", (session_id,))}
            plans = self._read("SELECT * FROM plans WHERE session_id=? ORDER BY id", (session_id,))
            decisions = self._read("SELECT * FROM decisions WHERE session_id=? ORDER BY id", (session_id,))
            events = self._read("SELECT * FROM robot_events WHERE session_id=? ORDER BY id", (session_id,))
            orow = self._read("SELECT * FROM outcomes WHERE session_id=?", (session_id,))
            vrows = (self._read("SELECT * FROM verifications WHERE session_id=? ORDER BY id", (session_id,))
                     if self._has_table("verifications") else [])   # a version-2 archive has none
        origin = f"{self.path}#session{session_id}"
        scene = Scene.from_json(json.loads(scenes["perceived"]["scene"]), origin)
        truth = Scene.from_json(json.loads(scenes["truth"]["scene"]), origin) if "truth" in scenes else None
        perception = json.loads(scenes["perceived"]["perception"]) if scenes["perceived"]["perception"] else None
        capture, overlay, missing = None, None, []
        if crow:
            capture, overlay, missing = self._load_images(crow[0])
        return SessionRecord(
            id=int(s["id"]), started=s["started"], source=s["source"], status=s["status"], task=s["task"],
            capture=capture, overlay=overlay, scene=scene, truth=truth, perception=perception,
            plans=tuple(PlanRecord(r["hash"], Plan.from_json(json.loads(r["plan"]), origin), r["created"],
                                   json.loads(r["preview"]) if r["preview"] else None) for r in plans),
            decisions=tuple({"id": r["id"], "plan_hash": r["plan_hash"], "decision": r["decision"],
                             "who": r["who"], "at": r["at"], "reason": r["reason"]} for r in decisions),
            robot_events=tuple({"id": r["id"], "plan_hash": r["plan_hash"], "at": r["at"], "kind": r["kind"],
                                "step": r["step"], "box": r["box"],
                                "detail": json.loads(r["detail"]) if r["detail"] else None} for r in events),
            outcome=json.loads(orow[0]["outcome"]) if orow else None,
            files=self.path.parent / s["files"] if s["files"] else None,
            missing_files=tuple(missing),
            verifications=tuple({"plan_hash": r["plan_hash"], "run": r["run"], "at": r["at"], "step": r["step"],
                                 "box": r["box"], "within": bool(r["within"]), "verdict": json.loads(r["verdict"]),
                                 "predicted": stored_scene(r["predicted"], origin),
                                 "observed": stored_scene(r["observed"], origin)} for r in vrows))

    def _load_images(self, row: sqlite3.Row) -> tuple[Capture | None, np.ndarray | None, list[str]]:
        """Images back as arrays; a deleted file is reported, not fatal (the record stays readable)."""
        import cv2

        from perception.capture import load_capture

        base = self.path.parent
        missing = [row[k] for k in ("rgb", "camera", "depth", "masks", "overlay")
                   if row[k] and not (base / row[k]).is_file()]
        capture = None
        if not {row["rgb"], row["camera"]} & set(missing) and not (row["depth"] and row["depth"] in missing):
            capture = load_capture(base / row["rgb"], base / row["depth"] if row["depth"] else None,
                                   base / row["camera"])
        overlay = None
        if row["overlay"] and row["overlay"] not in missing:
            img = cv2.imread(str(base / row["overlay"]), cv2.IMREAD_COLOR)
            overlay = cv2.cvtColor(img, cv2.COLOR_BGR2RGB) if img is not None else None
        return capture, overlay, missing

    def iter_sessions(self) -> Iterator[SessionRecord]:
        for s in self.list_sessions():
            yield self.load_session(int(s["id"]))


def _jsonable(obj: Any) -> Any:
    """json.dumps fallback for numpy scalars/arrays and tuples inside robot details."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if hasattr(obj, "to_json"):
        return obj.to_json()
    return str(obj)


__all__ = ["SessionStore", "SessionRecord", "PlanRecord", "StoreError", "DEFAULT_DB", "SCHEMA_VERSION",
           "utc_now"]
