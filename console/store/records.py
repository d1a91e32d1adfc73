"""What the session log hands back: frozen records of a stored session, built from its rows.

`SessionRecord` is everything stored for one session (images loaded back as
arrays, a deleted image file reported in `missing_files` rather than fatal,
so an archive that lost files still replays); `stored_scene` reads a
verification's shelf even when an older console stored a box out of bounds.
"""
from __future__ import annotations

import json
import sqlite3
from collections.abc import Sequence
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from shelfpick.perception.capture import Capture
from shelfpick.perception.scene import Scene
from shelfpick.planning.plan import Plan


def utc_now() -> str:
    """UTC time, ISO 8601 with milliseconds: sortable and unambiguous across machines."""
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds")


def jsonable(obj: Any) -> Any:
    """json.dumps fallback for numpy scalars/arrays and tuples inside robot details."""
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if hasattr(obj, "to_json"):
        return obj.to_json()
    return str(obj)


def stored_scene(text: str | None, origin: str = "") -> Scene | None:
    """A verification's stored shelf; a predicted box out of the shelf's bounds (stored by an
    older console: a box predicted to fall) is kept, so the record still replays."""
    if not text:
        return None
    from shelfpick.perception.errors import FormatError
    from shelfpick.perception.scene import Box, Shelf

    doc = json.loads(text)
    try:
        return Scene.from_json(doc, origin)
    except FormatError:
        if not isinstance(doc, dict) or not isinstance(doc.get("boxes"), list):
            raise
        return Scene(Shelf.from_json(doc["shelf"], origin),
                     tuple(Box.from_json(b, origin, f"boxes[{i}]") for i, b in enumerate(doc["boxes"])))


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
    labels: np.ndarray | None = None       # perception's masks (schema 4; None before, or unreadable)
    matter: np.ndarray | None = None       # perception's unexplained regions (label k+1 = unexplained[k])

    def plan(self, plan_hash: str) -> Plan:
        for p in self.plans:
            if p.hash == plan_hash:
                return p.plan
        raise KeyError(plan_hash)

    @property
    def n_boxes(self) -> int:
        return len(self.scene.boxes)


@dataclass(frozen=True)
class SessionRows:
    """One session's rows as read (under one lock) from every table."""

    session: sqlite3.Row
    capture: sqlite3.Row | None
    scenes: dict[str, sqlite3.Row]
    plans: Sequence[sqlite3.Row]
    decisions: Sequence[sqlite3.Row]
    events: Sequence[sqlite3.Row]
    outcome: sqlite3.Row | None
    verifications: Sequence[sqlite3.Row]


def session_record(rows: SessionRows, db_path: Path, origin: str) -> SessionRecord:
    """The record of one session from its rows; images are read from beside the database."""
    s, scenes = rows.session, rows.scenes
    scene = Scene.from_json(json.loads(scenes["perceived"]["scene"]), origin)
    truth = Scene.from_json(json.loads(scenes["truth"]["scene"]), origin) if "truth" in scenes else None
    perception = json.loads(scenes["perceived"]["perception"]) if scenes["perceived"]["perception"] else None
    capture, images, missing = None, {}, []
    if rows.capture is not None:
        capture, images, missing = load_images(rows.capture, db_path.parent,
                                               db_path.with_name(db_path.name + ".files"))
    return SessionRecord(
        id=int(s["id"]), started=s["started"], source=s["source"], status=s["status"], task=s["task"],
        capture=capture, overlay=images.get("overlay"), scene=scene, truth=truth, perception=perception,
        plans=tuple(PlanRecord(r["hash"], Plan.from_json(json.loads(r["plan"]), origin), r["created"],
                               json.loads(r["preview"]) if r["preview"] else None) for r in rows.plans),
        decisions=tuple({"id": r["id"], "plan_hash": r["plan_hash"], "decision": r["decision"],
                         "who": r["who"], "at": r["at"], "reason": r["reason"]} for r in rows.decisions),
        robot_events=tuple({"id": r["id"], "plan_hash": r["plan_hash"], "at": r["at"], "kind": r["kind"],
                            "step": r["step"], "box": r["box"],
                            "detail": json.loads(r["detail"]) if r["detail"] else None} for r in rows.events),
        outcome=json.loads(rows.outcome["outcome"]) if rows.outcome is not None else None,
        files=db_path.parent / s["files"] if s["files"] else None,
        missing_files=tuple(missing), labels=images.get("labels"), matter=images.get("matter"),
        verifications=tuple({"plan_hash": r["plan_hash"], "run": r["run"], "at": r["at"], "step": r["step"],
                             "box": r["box"], "within": bool(r["within"]), "verdict": json.loads(r["verdict"]),
                             "predicted": stored_scene(r["predicted"], origin),
                             "observed": stored_scene(r["observed"], origin)} for r in rows.verifications))


def _outside(rel: str, base: Path, root: Path | None) -> bool:
    """Whether a stored path leaves the session store's folder (`../`, absolute, a symlink out)."""
    return root is not None and not (base / rel).resolve().is_relative_to(root.resolve())


def load_images(row: sqlite3.Row, base: Path, root: Path | None = None
                ) -> tuple[Capture | None, dict[str, np.ndarray], list[str]]:
    """The capture and its illustrations back as arrays: the overlay and perception's label images
    (`labels`, `matter`: schema 4, none in an older log's row). A deleted file is reported, not
    fatal, and an illustration that cannot be read is reported and left out: the record stays
    readable. Only files inside `root` (the database's `<db>.files/`) are read: a stored path that
    leads out of it is reported as not read (a damaged or hostile archive must not embed other files)."""
    from shelfpick.perception.capture import load_capture, read_masks, read_rgb
    from shelfpick.perception.errors import PerceptionError

    stored = {k: row[k] for k in ("rgb", "camera", "depth", "masks", "overlay", "labels", "matter")
              if k in row.keys() and row[k]}
    refused = [rel for rel in stored.values() if _outside(rel, base, root)]
    missing = [rel for rel in stored.values() if rel not in refused and not (base / rel).is_file()]
    skip = set(missing) | set(refused)
    capture = None
    if not {row["rgb"], row["camera"]} & skip and stored.get("depth") not in skip:
        capture = load_capture(base / row["rgb"], base / stored["depth"] if "depth" in stored else None,
                               base / row["camera"])
    shape = (int(row["height"]), int(row["width"]))
    readers = {"overlay": read_rgb,        # bounded: the header is checked before decoding
               "labels": lambda p: read_masks(p, shape), "matter": lambda p: read_masks(p, shape)}
    images, unread = {}, []
    for key, read in readers.items():
        rel = stored.get(key)
        if rel and rel not in skip:
            try:
                images[key] = read(base / rel)
            except PerceptionError as exc:
                unread.append(f"{rel} (not read: {str(exc).split(': ', 1)[-1]})")
    shown = missing + [f"{r} (outside {root.name if root else 'the session store'}/: not read)" for r in refused]
    return capture, images, shown + unread
