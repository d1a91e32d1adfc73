"""The console's session log: one SQLite file in WAL mode, images as PNG files beside it.

Every operator and supervisor action is a row committed at once (WAL,
synchronous=FULL), so killing the server loses no record that was already
reported as written. Images would bloat the database and make it hard to
look at, so they live in `<db>.files/<session id>/` (rgb.png, depth.png,
camera.json, masks.png, masks.json, overlay.png, and perception's own label
images labels.png and matter.png) and the rows hold paths relative to the
database's folder.

viser runs callbacks on a thread pool, so one connection is shared behind a
lock (`check_same_thread=False`). A database that is locked by another
process, full or cannot be written raises `StoreError` with the path and the
cause; the workflow then refuses what needed the record (audit first).

`readonly=True` (`shelfpick sessions`, `shelfpick replay`) never writes: a
read-only archive lists and replays. A SQLite file that is not a shelfpick
session log is refused in either mode before anything is written to it
(console/store/schema.py: schema, migrations, opening).
The `runs` table says which console runs which plan: after a console died
mid-run (kill -9), `recover_interrupted` marks the run interrupted and the
acknowledged step unknown (whether a run's console is alive: an OS lock per
open store, console/store/owner.py); `step_states` is "never re-send a step",
keyed by session (one capture) and plan hash (console/store/steps.py).
"""
from __future__ import annotations

import json
import shutil
import sqlite3
import threading
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import numpy as np

from shelfpick.console.store import steps as store_steps
from shelfpick.console.store.owner import OwnerLock, owner_alive, sweep
from shelfpick.console.store.records import (
    PlanRecord,
    SessionRecord,
    SessionRows,
    jsonable,
    session_record,
    stored_scene,  # noqa: F401  (re-exported: benchmarks/closed_loop.py)
    utc_now,
)
from shelfpick.console.store.schema import (
    OUR_TABLES,  # noqa: F401  (re-exported)
    SCHEMA_VERSION,
    RunConflict,
    StoreError,
    explain,
    open_readonly,
    open_writable,
)
from shelfpick.perception.capture import Capture
from shelfpick.perception.scene import Scene
from shelfpick.planning.plan import Plan

DEFAULT_DB = Path("data") / "shelfpick.db"
ROBOT_KINDS = ("start", "sent", "ack", "done", "error", "aborted", "disconnected", "unknown")

T = TypeVar("T")


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
        as on a full disk). A writable store holds its owner lock (this
        console is alive) until `close()`.
        """
        import os
        import secrets
        import socket

        self.path = Path(path)
        self.files_root = self.path.with_name(self.path.name + ".files")
        self.readonly = bool(readonly)
        self._lock = threading.RLock()
        self._owner_lock: OwnerLock | None = None
        self.owner = f"{socket.gethostname()}:{os.getpid()}:{secrets.token_hex(4)}"
        if self.path.exists() and self.path.is_dir():
            raise StoreError(f"{self.path}: is a folder, expected a database file")
        if self.readonly:
            self._db = open_readonly(self.path)
            return
        self._db = open_writable(self.path, timeout, max_pages)
        try:
            self._owner_lock = OwnerLock(self.path, self.owner)
        except OSError as exc:
            self._db.close()
            raise StoreError(str(exc)) from None

    # ------------------------------------------------------------------ plumbing
    def _write(self, fn: Callable[[sqlite3.Cursor], T]) -> T:
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
                raise StoreError(explain(exc, self.path)) from None

    def _read(self, sql: str, args: tuple = ()) -> list[sqlite3.Row]:
        with self._lock:
            try:
                return self._db.execute(sql, args).fetchall()
            except sqlite3.Error as exc:
                raise StoreError(explain(exc, self.path)) from None

    def _require_session(self, cur: sqlite3.Cursor, session_id: int) -> None:
        if cur.execute("SELECT 1 FROM sessions WHERE id=?", (session_id,)).fetchone() is None:
            raise StoreError(f"{self.path}: no session with id {session_id}")

    def _has_table(self, name: str) -> bool:
        return bool(self._read("SELECT 1 FROM sqlite_master WHERE type='table' AND name=?", (name,)))

    def journal_mode(self) -> str:
        return str(self._read("PRAGMA journal_mode")[0][0]).lower()

    def close(self) -> None:
        if self._owner_lock is not None:
            self._owner_lock.release()
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
                    overlay: np.ndarray | None, perception: dict | None = None, *,
                    labels: np.ndarray | None = None, matter: np.ndarray | None = None) -> int:
        """Record a capture and its perceived (and, when known, true) scene; returns the id.
        `labels` and `matter` (perception's masks and unexplained regions, uint16 label images)
        let a replay draw the overlay again with the faces a plan set aside as matter.

        The row and the image files are written in one transaction: if the
        files cannot be written the row is rolled back and StoreError names
        the folder.
        """
        started = utc_now()

        def fn(cur: sqlite3.Cursor) -> int:
            cur.execute("INSERT INTO sessions(started, source, n_boxes, status) VALUES (?,?,?,?)",
                        (started, source, len(scene.boxes), "captured"))
            sid = int(cur.lastrowid)
            rel = self._save_images(sid, capture, overlay, {"labels": labels, "matter": matter})
            cur.execute("UPDATE sessions SET files=? WHERE id=?", (f"{self.files_root.name}/{sid}", sid))
            h, w = capture.shape
            cur.execute("INSERT INTO captures(session_id, rgb, depth, camera, masks, masks_json, overlay, "
                        "width, height, labels, matter) VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                        (sid, rel["rgb"], rel.get("depth"), rel["camera"], rel.get("masks"),
                         rel.get("masks_json"), rel.get("overlay"), w, h, rel.get("labels"), rel.get("matter")))
            cur.execute("INSERT INTO scenes(session_id, kind, scene, perception) VALUES (?,?,?,?)",
                        (sid, "perceived", json.dumps(scene.to_json()),
                         json.dumps(perception) if perception is not None else None))
            if truth is not None:
                cur.execute("INSERT INTO scenes(session_id, kind, scene) VALUES (?,?,?)",
                            (sid, "truth", json.dumps(truth.to_json())))
            return sid

        return self._write(fn)

    def _save_images(self, sid: int, capture: Capture, overlay: np.ndarray | None,
                     label_images: dict[str, np.ndarray | None]) -> dict[str, str]:
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
            for key, img in label_images.items():     # perceived labels.png, matter.png (uint16)
                if img is not None and np.asarray(img).shape == capture.shape:
                    paths[key] = d / f"{key}.png"
                    if not cv2.imwrite(str(paths[key]), np.asarray(img).astype(np.uint16)):
                        raise OSError(f"cannot write {paths[key]}")
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

    def add_preview_worlds(self, session_id: int, plan_hash: str, planner: str,
                           worlds: dict[int, dict]) -> None:
        """Add to a stored plan's preview the sample world each risky step is shown in (recorded after
        the plan, off the click path), so the replay and the HTML show the collapse the live page did.
        Only the preview changes (display data): the plan, its hash and the decisions stay as stored."""
        def fn(cur: sqlite3.Cursor) -> None:
            row = cur.execute("SELECT id, preview FROM plans WHERE session_id=? AND hash=? AND planner=? "
                              "ORDER BY id DESC LIMIT 1", (session_id, plan_hash, planner)).fetchone()
            if row is None or not row[1]:
                return
            steps = json.loads(row[1])
            for k, doc in worlds.items():
                if 0 <= int(k) < len(steps) and isinstance(steps[int(k)], dict):
                    steps[int(k)]["collapse_world"] = doc
            cur.execute("UPDATE plans SET preview=? WHERE id=?", (json.dumps(steps, default=jsonable), row[0]))

        self._write(fn)

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
                     json.dumps(detail, default=jsonable) if detail is not None else None))
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
        One run at a time per database: an open run of a console that is
        alive (this one or another process) refuses the start (`RunConflict`),
        checked inside the write transaction, so two consoles cannot both start.
        """
        def fn(cur: sqlite3.Cursor) -> int:
            self._require_session(cur, session_id)
            open_run = cur.execute("SELECT id FROM runs WHERE session_id=? AND ended IS NULL",
                                   (session_id,)).fetchone()
            if open_run is not None:
                raise RunConflict(f"{self.path}: session {session_id} already has a run in progress "
                                  f"(run {open_run[0]})")
            self._refuse_a_live_run(cur)
            cur.execute("INSERT INTO runs(session_id, plan_hash, decision_id, owner, started) VALUES (?,?,?,?,?)",
                        (session_id, plan_hash, decision_id, self.owner, utc_now()))
            rid = int(cur.lastrowid)
            self._insert_event(cur, session_id, plan_hash, "start", None, None, {**detail, "run": rid})
            return rid

        return self._write(fn)

    def _refuse_a_live_run(self, cur: sqlite3.Cursor) -> None:
        """RunConflict when any console that is alive has a run open on this database."""
        for row in cur.execute("SELECT id, session_id, plan_hash, owner FROM runs WHERE ended IS NULL "
                               "ORDER BY id").fetchall():
            if owner_alive(row["owner"], self.path):
                who = "this console" if row["owner"] == self.owner else f"another console ({row['owner']})"
                raise RunConflict(f"{self.path}: {who} is running plan {row['plan_hash']} of session "
                                  f"{row['session_id']} (run {row['id']}) on this database; one run at a "
                                  f"time: wait for it to end or press Stop there")

    def active_run(self) -> dict | None:
        """The open run of a console that is alive (any process), or None: what a second run waits for."""
        for row in self._read("SELECT id, session_id, plan_hash, owner FROM runs WHERE ended IS NULL ORDER BY id"):
            if owner_alive(row["owner"], self.path):
                return dict(row)
        return None

    def add_verification(self, session_id: int, plan_hash: str, run: str | None, verdict: dict,
                         predicted: Scene | None, observed: Scene | None) -> int:
        """The look after one step: the verdict, the predicted and the observed shelf (before the next step)."""
        def fn(cur: sqlite3.Cursor) -> int:
            self._require_session(cur, session_id)
            cur.execute("INSERT INTO verifications(session_id, plan_hash, run, at, step, box, within, verdict, "
                        "predicted, observed) VALUES (?,?,?,?,?,?,?,?,?,?)",
                        (session_id, plan_hash, run, utc_now(), int(verdict["step"]), verdict.get("box"),
                         1 if verdict.get("within") else 0, json.dumps(verdict, default=jsonable),
                         json.dumps(predicted.to_json()) if predicted is not None else None,
                         json.dumps(observed.to_json()) if observed is not None else None))
            return int(cur.lastrowid)

        return self._write(fn)

    def set_outcome(self, session_id: int, outcome: dict, run_id: int | None = None) -> None:
        """The run's outcome; the session's status says done, held, stopped, interrupted or failed."""
        ok = bool(outcome.get("ok"))
        status = ("done" if ok else "interrupted" if outcome.get("interrupted")
                  else "stopped" if outcome.get("stopped") else "held" if outcome.get("held") else "failed")

        def fn(cur: sqlite3.Cursor) -> None:
            self._require_session(cur, session_id)
            cur.execute("INSERT OR REPLACE INTO outcomes(session_id, at, outcome) VALUES (?,?,?)",
                        (session_id, utc_now(), json.dumps(outcome, default=jsonable)))
            cur.execute("UPDATE sessions SET status=? WHERE id=?", (status, session_id))
            if run_id is not None:
                cur.execute("UPDATE runs SET ended=?, result=? WHERE id=?", (utc_now(), status, run_id))

        self._write(fn)

    # ------------------------------------------------------------------ steps and runs
    def step_states(self, session_id: int, plan_hash: str) -> dict[int, tuple[str, str | None]]:
        """step -> (state, box) from the robot events of this session's runs of this plan.

        state: `sent` (its record committed before it went out, nothing
        after), `in_flight` (acknowledged, not finished), `done`, `failed`,
        `aborted` or `unknown` (in flight when the link or the console died).
        This is what "never re-send a step" is keyed by: session (one capture)
        and plan, stored, so it holds after a restart.
        """
        rows = self._read("SELECT kind, step, box, detail FROM robot_events WHERE session_id=? AND "
                          "plan_hash=? AND step IS NOT NULL ORDER BY id", (session_id, plan_hash))
        return store_steps.step_states(rows)

    def recover_interrupted(self) -> list[dict]:
        """Runs whose console died (kill -9, power cut) while executing: mark them interrupted.

        A step that was sent (or acknowledged) but not finished gets an
        `unknown` event (the robot may have moved it or not: the operator is
        told to look at the shelf), never `not_sent`; the session gets an
        outcome saying so and the status `interrupted`. Runs of a console that
        is still alive (its store holds its owner lock) are left alone; lock
        files that crashed consoles left behind are removed. Returns one dict
        per recovered run.
        """
        if self.readonly:
            return []
        runs = self._read("SELECT * FROM runs WHERE ended IS NULL ORDER BY id")
        found = [self._interrupt(run) for run in runs if not owner_alive(run["owner"], self.path)]
        sweep(self.path)
        return found

    def _interrupt(self, run: sqlite3.Row) -> dict:
        sid, h = int(run["session_id"]), run["plan_hash"]
        plan_row = self._read("SELECT plan FROM plans WHERE session_id=? AND hash=? ORDER BY id DESC LIMIT 1",
                              (sid, h))
        sequence = json.loads(plan_row[0]["plan"]).get("sequence", []) if plan_row else []
        rec = store_steps.interrupted_run(h, sequence, self.step_states(sid, h))

        def fn(cur: sqlite3.Cursor) -> None:
            for i, box in rec.unknown:
                reason = rec.outcome["steps"][i]["detail"]["reason"] if i < len(rec.outcome["steps"]) \
                    else store_steps.INTERRUPTED_REASON
                self._insert_event(cur, sid, h, "unknown", i, box, {"reason": reason})
            cur.execute("INSERT OR IGNORE INTO outcomes(session_id, at, outcome) VALUES (?,?,?)",
                        (sid, utc_now(), json.dumps(rec.outcome)))
            cur.execute("UPDATE sessions SET status='interrupted' WHERE id=?", (sid,))
            cur.execute("UPDATE runs SET ended=?, result='interrupted' WHERE id=?", (utc_now(), run["id"]))

        self._write(fn)
        return {"session": sid, "plan": h, "unknown": rec.unknown, "completed": rec.completed}

    def verification_stats(self) -> list[dict]:
        """Every verified step of every session: plan hash, step, within, and the plan's predicted risk."""
        if not self._has_table("verifications"):
            return []
        return store_steps.verification_stats(self._read(
            "SELECT v.session_id, v.plan_hash, v.step, v.box, v.within, v.verdict, "
            "(SELECT p.plan FROM plans p WHERE p.session_id=v.session_id AND p.hash=v.plan_hash "
            "ORDER BY p.id DESC LIMIT 1) AS plan FROM verifications v ORDER BY v.id"))

    def step_stats(self) -> list[dict]:
        """Every step a robot reported done, in every session: the plan's predicted risk for it,
        whether the robot reported boxes collapsing, and the look after it (None: not verified)."""
        rows = self._read("SELECT e.session_id, e.plan_hash, e.kind, e.step, e.box, e.detail, "
                          "(SELECT p.plan FROM plans p WHERE p.session_id=e.session_id AND p.hash=e.plan_hash "
                          "ORDER BY p.id DESC LIMIT 1) AS plan FROM robot_events e "
                          "WHERE e.kind IN ('done', 'error') AND e.step IS NOT NULL ORDER BY e.id")
        return store_steps.step_stats(rows, self.verification_stats())

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
        """Everything stored for one session (StoreError if there is none)."""
        with self._lock:
            srow = self._read("SELECT * FROM sessions WHERE id=?", (session_id,))
            if not srow:
                raise StoreError(f"{self.path}: no session with id {session_id}")
            crow = self._read("SELECT * FROM captures WHERE session_id=?", (session_id,))
            scenes = {r["kind"]: r for r in self._read("SELECT * FROM scenes WHERE session_id=?", (session_id,))}
            plans = self._read("SELECT * FROM plans WHERE session_id=? ORDER BY id", (session_id,))
            decisions = self._read("SELECT * FROM decisions WHERE session_id=? ORDER BY id", (session_id,))
            events = self._read("SELECT * FROM robot_events WHERE session_id=? ORDER BY id", (session_id,))
            orow = self._read("SELECT * FROM outcomes WHERE session_id=?", (session_id,))
            vrows = (self._read("SELECT * FROM verifications WHERE session_id=? ORDER BY id", (session_id,))
                     if self._has_table("verifications") else [])   # a version-2 archive has none
        rows = SessionRows(srow[0], crow[0] if crow else None, scenes, plans, decisions, events,
                           orow[0] if orow else None, vrows)
        return session_record(rows, self.path, f"{self.path}#session{session_id}")

    def iter_sessions(self) -> Iterator[SessionRecord]:
        for s in self.list_sessions():
            yield self.load_session(int(s["id"]))


__all__ = ["SessionStore", "SessionRecord", "PlanRecord", "StoreError", "RunConflict", "DEFAULT_DB", "SCHEMA_VERSION",
           "utc_now"]
