"""The console's session log: one SQLite file in WAL mode, images as PNG files beside it.

Every operator and supervisor action is a row committed at once (WAL,
synchronous=FULL), so killing the server loses no record that was already
reported as written. Images would bloat the database and make it hard to
look at, so they live in `<db>.files/<session id>/` (rgb.png, depth.png,
camera.json, masks.png, masks.json, overlay.png) and the rows hold paths
relative to the database's folder.

viser runs callbacks on a thread pool, so one connection is shared behind a
lock (`check_same_thread=False`). A database that is locked by another
process or cannot be written raises `StoreError` with the path and the cause;
the caller keeps its in-memory session and tells the user.
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
SCHEMA_VERSION = 1

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
CREATE INDEX IF NOT EXISTS plans_session ON plans(session_id);
CREATE INDEX IF NOT EXISTS decisions_session ON decisions(session_id);
CREATE INDEX IF NOT EXISTS events_session ON robot_events(session_id);
"""


class StoreError(ShelfpickError):
    """The session database cannot be opened or written (locked, read-only, corrupt)."""


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
    if "not a database" in low or "malformed" in low:
        return f"{path}: not a shelfpick session database or corrupt ({msg})"
    return f"{path}: database error ({exc.__class__.__name__}: {msg})"


class SessionStore:
    """The session log of one console (thread safe; every write committed at once)."""

    def __init__(self, path: str | Path, *, timeout: float = 5.0) -> None:
        self.path = Path(path)
        self.files_root = self.path.with_name(self.path.name + ".files")
        self._lock = threading.RLock()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreError(f"{self.path}: cannot create the database folder ({exc})") from None
        if self.path.exists() and self.path.is_dir():
            raise StoreError(f"{self.path}: is a folder, expected a database file")
        if self.path.exists() and not self.path.stat().st_mode & 0o222:
            # honour a file marked read-only even when running as root (root ignores modes)
            raise StoreError(f"{self.path}: database cannot be written (file is read-only, mode "
                             f"{self.path.stat().st_mode & 0o777:o}); make it writable or use another --db")
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
        except sqlite3.Error as exc:
            raise StoreError(_explain(exc, self.path)) from None

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
                cur.execute("COMMIT")
            except BaseException:
                if self._db.in_transaction:
                    self._db.execute("ROLLBACK")
                raise

    def _write(self, fn) -> Any:
        """Run fn(cursor) inside BEGIN IMMEDIATE ... COMMIT under the lock; map errors."""
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
        def fn(cur: sqlite3.Cursor) -> int:
            self._require_session(cur, session_id)
            cur.execute("INSERT INTO robot_events(session_id, plan_hash, at, kind, step, box, detail) "
                        "VALUES (?,?,?,?,?,?,?)",
                        (session_id, plan_hash, utc_now(), kind, step, box,
                         json.dumps(detail, default=_jsonable) if detail is not None else None))
            eid = int(cur.lastrowid)
            cur.execute("UPDATE sessions SET status='executing' WHERE id=? AND status NOT IN ('done', 'failed')",
                        (session_id,))
            return eid

        return self._write(fn)

    def set_outcome(self, session_id: int, outcome: dict) -> None:
        ok = bool(outcome.get("ok"))

        def fn(cur: sqlite3.Cursor) -> None:
            self._require_session(cur, session_id)
            cur.execute("INSERT OR REPLACE INTO outcomes(session_id, at, outcome) VALUES (?,?,?)",
                        (session_id, utc_now(), json.dumps(outcome, default=_jsonable)))
            cur.execute("UPDATE sessions SET status=? WHERE id=?", ("done" if ok else "failed", session_id))

        self._write(fn)

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
            missing_files=tuple(missing))

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


__all__ = ["SessionStore", "SessionRecord", "PlanRecord", "StoreError", "DEFAULT_DB", "utc_now"]
