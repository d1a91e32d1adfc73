"""Did the shelf do what the plan predicted? One step's predicted shelf against the observed one.

After the robot reports a step done, the console looks again (a new capture,
perceived) and compares what it sees with the shelf the plan predicted after
that step (`planning/predicted.py`). Boxes are matched by their front-face
centres, the one thing a camera measures well; ids do not help (perception
numbers the boxes of every capture afresh).

Tolerance (docs/console.md, "Verification"): a remaining box whose front-face
centre is more than 3 cm from where it was predicted, or that turned more than
8 degrees, has moved; a predicted box with no observed box within 10 cm is
missing, an observed box with no predicted one is new. Any of these holds the
robot before the next step. The 3 cm / 8 degrees are the smallest round
figures above what perception alone gives for a box that did not move
(benchmarks/closed_loop.py measures it: the 99th percentile of a still box's
apparent motion between two renders is about 1.5 cm and 3 degrees), and well
below what a collapse does (a falling box moves by its own height, 17-25 cm).

Pure functions of scenes: no camera, no robot, no I/O.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

from perception.scene import Box, Scene

STATUSES = ("ok", "moved", "missing", "new")


@dataclass(frozen=True)
class Tolerance:
    """How far a box may be from its predicted pose before the robot is held."""

    displacement: float = 0.03   # m, front-face centre
    rotation: float = 10.0       # degrees, up to the box's symmetries
    match_radius: float = 0.10   # m: a box farther than this from every prediction is another box

    def to_json(self) -> dict:
        return {"displacement_m": self.displacement, "rotation_deg": self.rotation,
                "match_radius_m": self.match_radius}

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> "Tolerance":
        return cls(float(doc.get("displacement_m", 0.03)), float(doc.get("rotation_deg", 10.0)),
                   float(doc.get("match_radius_m", 0.10)))


@dataclass(frozen=True)
class BoxDiff:
    """One box of the comparison: predicted id, observed id (None when missing / new), how far off."""

    predicted: str | None
    observed: str | None
    displacement: float = 0.0    # m
    rotation: float = 0.0        # degrees
    status: str = "ok"

    def to_json(self) -> dict:
        return {"predicted": self.predicted, "observed": self.observed,
                "displacement_m": round(self.displacement, 4), "rotation_deg": round(self.rotation, 2),
                "status": self.status}

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> "BoxDiff":
        status = doc.get("status", "ok")
        if status not in STATUSES:
            raise ValueError(f"verification box status: expected one of {', '.join(STATUSES)}, got {status!r}")
        return cls(doc.get("predicted"), doc.get("observed"), float(doc.get("displacement_m", 0.0)),
                   float(doc.get("rotation_deg", 0.0)), status)


@dataclass(frozen=True)
class Verification:
    """The verdict after one step: within tolerance (the next step may go) or not (hold)."""

    step: int
    box: str
    within: bool
    boxes: tuple[BoxDiff, ...] = ()
    tolerance: Tolerance = field(default_factory=Tolerance)
    unavailable: str | None = None   # why no comparison could be made (then `within` is False)
    timing: Mapping[str, float] = field(default_factory=dict, compare=False)

    def ids(self, status: str) -> tuple[str, ...]:
        """Predicted ids (observed ids for `new`) with this status."""
        return tuple((d.observed if status == "new" else d.predicted) or "" for d in self.boxes
                     if d.status == status)

    @property
    def max_displacement(self) -> float:
        return max((d.displacement for d in self.boxes if d.status in ("ok", "moved")), default=0.0)

    def observed_of(self) -> dict[str, str]:
        """Predicted id -> observed id, for every matched box (moved or not)."""
        return {d.predicted: d.observed for d in self.boxes
                if d.predicted is not None and d.observed is not None}

    def summary(self) -> str:
        """One line for the page and the log (contains box ids: escape before showing)."""
        if self.unavailable:
            return f"step {self.step + 1} ({self.box}): not verified: {self.unavailable}"
        if self.within:
            return (f"step {self.step + 1} ({self.box}): shelf as predicted "
                    f"(largest difference {100 * self.max_displacement:.1f} cm)")
        parts = []
        moved = [d for d in self.boxes if d.status == "moved"]
        if moved:
            parts.append("moved: " + ", ".join(f"{d.predicted} {100 * d.displacement:.1f} cm"
                                               + (f" {d.rotation:.0f} deg" if d.rotation > self.tolerance.rotation
                                                  else "") for d in moved))
        if self.ids("missing"):
            parts.append("missing: " + ", ".join(self.ids("missing")))
        if self.ids("new"):
            parts.append("not predicted: " + ", ".join(self.ids("new")) + " (observed ids)")
        return f"step {self.step + 1} ({self.box}): the shelf differs from the prediction: " + "; ".join(parts)

    def to_json(self) -> dict:
        doc: dict[str, Any] = {"step": self.step, "box": self.box, "within": self.within,
                               "tolerance": self.tolerance.to_json(), "boxes": [d.to_json() for d in self.boxes],
                               "max_displacement_m": round(self.max_displacement, 4),
                               "summary": self.summary()}
        if self.unavailable:
            doc["unavailable"] = self.unavailable
        if self.timing:
            doc["timing"] = {k: round(float(v), 4) for k, v in self.timing.items()}
        return doc

    @classmethod
    def from_json(cls, doc: Mapping[str, Any]) -> "Verification":
        return cls(int(doc["step"]), str(doc["box"]), bool(doc["within"]),
                   tuple(BoxDiff.from_json(d) for d in doc.get("boxes", [])),
                   Tolerance.from_json(doc.get("tolerance", {})), doc.get("unavailable"),
                   dict(doc.get("timing", {})))


def unavailable(step: int, box: str, why: str, tolerance: Tolerance | None = None) -> Verification:
    """No comparison could be made (no new frame, perception failed): that is a hold, never a pass."""
    return Verification(step, box, False, (), tolerance or Tolerance(), why)


# --------------------------------------------------------------------------
def _qmul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw)


def _qconj(q: Sequence[float]) -> tuple[float, float, float, float]:
    return (q[0], -q[1], -q[2], -q[3])


_S = math.sqrt(0.5)
# rotations (body frame) that leave a box looking the same from the front: about its depth axis
# by quarter turns (a face reported with width and height swapped) and the half turn about z
# (front and back faces swapped)
_SYMMETRIES = tuple(_qmul(y, z) for y in ((1.0, 0.0, 0.0, 0.0), (_S, 0.0, _S, 0.0), (0.0, 0.0, 1.0, 0.0),
                                          (_S, 0.0, -_S, 0.0))
                    for z in ((1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)))


def rotation_deg(a: Box, b: Box) -> float:
    """Smallest angle (degrees) between two box orientations, up to the box's front-view symmetries."""
    best = 180.0
    for s in _SYMMETRIES:
        rel = _qmul(_qconj(a.orientation), _qmul(b.orientation, s))
        w = min(1.0, abs(rel[0]))
        best = min(best, math.degrees(2.0 * math.acos(w)))
    return best


def compare(predicted: Scene, observed: Scene, step: int, box: str,
            tolerance: Tolerance | None = None) -> Verification:
    """Match observed boxes to predicted ones (closest front-face centres first) and judge.

    Every predicted box gets at most one observed box within `match_radius`;
    the pairs are taken closest first, so a box that fell onto its neighbour's
    place does not steal the neighbour's match unless it is closer.
    """
    tol = tolerance or Tolerance()
    pairs = []
    for p in predicted.boxes:
        fp = p.front_center
        for o in observed.boxes:
            d = math.dist(fp, o.front_center)
            if d <= tol.match_radius:
                pairs.append((d, p.id, o.id))
    pairs.sort()
    matched: dict[str, tuple[str, float]] = {}
    used: set[str] = set()
    for d, pid, oid in pairs:
        if pid not in matched and oid not in used:
            matched[pid] = (oid, d)
            used.add(oid)
    diffs = []
    for p in predicted.boxes:
        if p.id not in matched:
            diffs.append(BoxDiff(p.id, None, 0.0, 0.0, "missing"))
            continue
        oid, d = matched[p.id]
        rot = rotation_deg(p, observed.box(oid))
        status = "moved" if d > tol.displacement or rot > tol.rotation else "ok"
        diffs.append(BoxDiff(p.id, oid, d, rot, status))
    diffs.extend(BoxDiff(None, o.id, 0.0, 0.0, "new") for o in observed.boxes if o.id not in used)
    within = all(d.status == "ok" for d in diffs)
    return Verification(step, box, within, tuple(diffs), tol)


__all__ = ["Tolerance", "BoxDiff", "Verification", "compare", "unavailable", "rotation_deg", "STATUSES"]
