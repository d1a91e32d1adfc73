"""What happened to the shelf when one box was pulled out: the verdict of one trial."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

from shelfpick.perception.scene import Quat, Vec3

Frame = tuple[float, dict[str, tuple[Vec3, Quat]]]   # (sim time, box -> pose) of a recorded pull


@dataclass(frozen=True)
class StepResult:
    """What happened to the shelf when `box` was pulled out.

    `moved` are the other boxes that started moving (past the onset threshold),
    ordered by when they started; `collapsed` the subset past the collapse
    thresholds, in the same order (the first one drives backtracking);
    `collided` the neighbours the box or the gripper touched that then moved.
    """

    box: str
    extracted: bool
    collapsed: tuple[str, ...] = ()
    collided: tuple[str, ...] = ()
    displacement: Mapping[str, float] = field(default_factory=dict)
    rotation: Mapping[str, float] = field(default_factory=dict)
    moved: tuple[str, ...] = ()
    frames: tuple[Frame, ...] = ()
    sim_time: float = 0.0
    note: str = ""

    @property
    def ok(self) -> bool:
        """The box came out and nothing else collapsed."""
        return self.extracted and not self.collapsed

    @property
    def collision(self) -> bool:
        return bool(self.collided)

    def to_json(self, frames: bool = False) -> dict:
        doc: dict[str, Any] = {
            "box": self.box, "extracted": self.extracted, "ok": self.ok,
            "collapse": bool(self.collapsed), "collision": bool(self.collided),
            "collapsed": list(self.collapsed), "collided": list(self.collided),
            "moved": {b: round(self.displacement.get(b, 0.0), 4) for b in self.moved},
            "displacement": {k: round(v, 4) for k, v in self.displacement.items()},
            "rotation_deg": {k: round(v, 2) for k, v in self.rotation.items()},
            "sim_time": round(self.sim_time, 4),
        }
        if self.note:
            doc["note"] = self.note
        if frames and self.frames:
            doc["frames"] = [[t, {k: [list(p), list(q)] for k, (p, q) in poses.items()}]
                             for t, poses in self.frames]
        return doc
