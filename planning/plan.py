"""Plan documents (`shelfpick.plan/1`) and the per-step prediction they carry."""
from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any, Mapping

from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Scene, check_id, read_json, write_json
from shelfpick.planning.physics import PhysicsConfig

PLAN_FORMAT = "shelfpick.plan/1"
TASKS = ("extract", "clear")
PLANNERS = ("physics", "heuristic")   # what a plan's `planner` may be
# the physics settings a reader needs to judge a plan (all of them: `physics.config_hash`)
PHYSICS_RECORDED = ("gravity", "lateral_friction", "spinning_friction", "density", "time_step",
                    "solver_iterations", "pull_speed", "pull_force", "disturbance", "collapse_displacement",
                    "collapse_rotation", "collision_threshold")


def shelfpick_version() -> str:
    """The installed shelfpick's version (pyproject.toml); 'unknown' when run from a bare checkout."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("shelfpick")
    except PackageNotFoundError:
        return "unknown"


def scene_hash(scene: Scene) -> str:
    """Identity of the scene a plan was made for: sha256 of its canonical JSON (sorted keys, no spaces)."""
    doc = json.dumps(scene.to_json(), sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(doc.encode()).hexdigest()[:16]


def provenance(scene: Scene, config: Any = None, samples: int | None = None,
               risk: float | None = None, cell: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """What made a plan, so that a plan file can be checked against its scene and reproduced
    (`cell`: the cell file whose priors the worlds drew, as `shelfpick plan --cell` records it)."""

    cfg = asdict(config if config is not None else PhysicsConfig())
    physics = {k: cfg[k] for k in PHYSICS_RECORDED if k in cfg}
    physics["config_hash"] = hashlib.sha256(json.dumps(cfg, sort_keys=True, default=str).encode()).hexdigest()[:16]
    doc: dict[str, Any] = {"shelfpick_version": shelfpick_version(), "scene_hash": scene_hash(scene),
                           "physics": physics}
    if samples is not None:
        doc["samples"] = samples
    if risk is not None:
        doc["risk"] = risk
    if cell is not None:
        doc["cell"] = dict(cell)
    return doc


@dataclass(frozen=True)
class StepPrediction:
    """What the simulation predicts for removing `box` at this point of the plan.

    `collapse_prob` is the fraction of depth samples in which another box
    collapsed; `collision_prob` the fraction in which the pulled box (or the
    gripper) disturbed a neighbour; `moved` every box that moved in any
    sample, in the order they first started moving.
    """

    box: str
    collapse_prob: float = 0.0
    collision_prob: float = 0.0
    moved: tuple[str, ...] = ()

    @property
    def risk(self) -> float:
        return max(self.collapse_prob, self.collision_prob)

    def to_json(self) -> dict:
        return {"box": self.box, "collapse_prob": self.collapse_prob,
                "collision_prob": self.collision_prob, "moved": list(self.moved)}

    @classmethod
    def from_json(cls, doc: Any, origin: str = "", where: str = "predicted") -> "StepPrediction":
        if not isinstance(doc, Mapping) or not isinstance(doc.get("box"), str):
            raise FormatError(origin, where, f"expected an object with a string 'box', got {doc!r}")
        check_id(doc["box"], origin, f"{where}.box")
        probs = []
        for k in ("collapse_prob", "collision_prob"):
            v = doc.get(k, 0.0)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
                raise FormatError(origin, f"{where}.{k}", f"expected a probability in [0, 1], got {v!r}")
            probs.append(float(v))
        moved = doc.get("moved", [])
        if not isinstance(moved, list) or not all(isinstance(m, str) for m in moved):
            raise FormatError(origin, f"{where}.moved", f"expected a list of box ids, got {moved!r}")
        for i, m in enumerate(moved):
            check_id(m, origin, f"{where}.moved[{i}]")
        return cls(doc["box"], probs[0], probs[1], tuple(moved))


def _check_safe(safe: bool, predicted: tuple[StepPrediction, ...], prov: Mapping, origin: str) -> None:
    """A plan that says `safe: true` has no step riskier than the threshold it was planned with
    (`provenance.risk`, 0 when not recorded): the planner never writes otherwise, and the console
    and `simulate` trust the flag."""
    threshold = prov.get("risk", 0.0)
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not 0.0 <= threshold <= 1.0:
        raise FormatError(origin, "provenance.risk", f"expected a probability in [0, 1], got {threshold!r}")
    worst = max(range(len(predicted)), key=lambda i: predicted[i].risk, default=None)
    if safe and worst is not None and predicted[worst].risk > threshold:
        raise FormatError(origin, "safe", f"true, but step {worst + 1} ({predicted[worst].box!r}) has predicted "
                          f"risk {predicted[worst].risk:g} above the plan's threshold {threshold:g} "
                          "(provenance.risk)")


def _check_gated(safe: bool, gated: Any, origin: str) -> None:
    """A plan that says `safe: true` after the gate has the upper end of its calibrated chance of a
    collapse below its threshold (`search.plan_risk`): the planner never writes otherwise."""
    where = "search.plan_risk"
    if not isinstance(gated, Mapping):
        raise FormatError(origin, where, f"expected an object, got {gated!r}")
    vals = {}
    for k in ("probability", "low", "high", "max_plan_risk"):
        v = gated.get(k)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1.0:
            raise FormatError(origin, f"{where}.{k}", f"expected a probability in [0, 1], got {v!r}")
        vals[k] = float(v)
    if safe and not vals["high"] < vals["max_plan_risk"]:
        raise FormatError(origin, "safe", f"true, but the plan's calibrated risk reaches {vals['high']:g}, not below "
                          f"its threshold {vals['max_plan_risk']:g} ({where})")


@dataclass(frozen=True)
class Plan:
    """An ordered removal sequence and what the planner predicted for it."""

    task: str
    target: str | None
    planner: str
    sequence: tuple[str, ...]
    predicted: tuple[StepPrediction, ...] = ()
    safe: bool = True
    timing: Mapping[str, float] = field(default_factory=dict, compare=False, hash=False)
    seed: int | None = None
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, hash=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "sequence", tuple(self.sequence))
        object.__setattr__(self, "predicted", tuple(self.predicted))

    @property
    def risk(self) -> float:
        """Largest predicted step risk (0 when nothing is predicted to move)."""
        return max((p.risk for p in self.predicted), default=0.0)

    @property
    def provenance(self) -> Mapping[str, Any]:
        """`shelfpick_version`, `scene_hash`, `physics`... (empty for plans written before 0.2)."""
        doc = self.extra.get("provenance")
        return doc if isinstance(doc, Mapping) else {}

    def with_provenance(self, scene: Scene, config: Any = None, samples: int | None = None,
                        risk: float | None = None, cell: Mapping[str, Any] | None = None) -> "Plan":
        """This plan recording what made it (see `provenance`); sequence and predictions unchanged."""
        return replace(self, extra={**self.extra, "provenance": provenance(scene, config, samples, risk, cell)})

    def content_hash(self) -> str:
        """Identity of what the robot would do: task, target and the exact sequence."""
        key = json.dumps({"task": self.task, "target": self.target, "sequence": list(self.sequence)},
                         sort_keys=True)
        return hashlib.sha256(key.encode()).hexdigest()[:16]

    def to_json(self) -> dict:
        doc: dict[str, Any] = dict(self.extra)
        doc.update({"format": PLAN_FORMAT, "task": self.task, "target": self.target,
                    "planner": self.planner, "sequence": list(self.sequence), "safe": self.safe})
        if self.predicted:
            doc["predicted"] = [p.to_json() for p in self.predicted]
        if self.timing:
            doc["timing"] = dict(self.timing)
        if self.seed is not None:
            doc["seed"] = self.seed
        return doc

    @classmethod
    def from_json(cls, doc: Any, origin: str = "") -> "Plan":
        if not isinstance(doc, Mapping):
            raise FormatError(origin, "plan", f"expected an object, got {type(doc).__name__}")
        for k in ("format", "task", "target", "planner", "sequence"):
            if k not in doc:
                raise FormatError(origin, k, "missing required key")
        if doc["format"] != PLAN_FORMAT:
            raise FormatError(origin, "format", f"expected {PLAN_FORMAT!r}, got {doc['format']!r}")
        task = doc["task"]
        if task not in TASKS:
            raise FormatError(origin, "task", f"expected one of {', '.join(TASKS)}, got {task!r}")
        target = doc["target"]
        if task == "extract" and not isinstance(target, str):
            raise FormatError(origin, "target", f"an extract plan needs a box id, got {target!r}")
        if task == "clear" and target is not None:
            raise FormatError(origin, "target", f"a clear plan has target null, got {target!r}")
        seq = doc["sequence"]
        if not isinstance(seq, list) or not all(isinstance(s, str) for s in seq):
            raise FormatError(origin, "sequence", f"expected a list of box ids, got {seq!r}")
        for i, b in enumerate(seq):
            check_id(b, origin, f"sequence[{i}]")
        if isinstance(target, str):
            check_id(target, origin, "target")
        if len(set(seq)) != len(seq):
            raise FormatError(origin, "sequence", f"a box appears twice: {seq!r}")
        if task == "extract" and (not seq or seq[-1] != target):
            raise FormatError(origin, "sequence", f"an extract plan must end with its target {target!r}, got {seq!r}")
        planner = doc["planner"]
        if not isinstance(planner, str):
            raise FormatError(origin, "planner", f"expected a string, got {planner!r}")
        raw_pred = doc.get("predicted", [])
        if not isinstance(raw_pred, list):
            raise FormatError(origin, "predicted", f"expected a list, got {raw_pred!r}")
        predicted = tuple(StepPrediction.from_json(p, origin, f"predicted[{i}]") for i, p in enumerate(raw_pred))
        safe = doc.get("safe", True)
        if not isinstance(safe, bool):
            raise FormatError(origin, "safe", f"expected true or false, got {safe!r}")
        timing = doc.get("timing", {})
        if not isinstance(timing, Mapping):
            raise FormatError(origin, "timing", f"expected an object, got {timing!r}")
        for k, v in timing.items():
            if isinstance(v, bool) or not isinstance(v, (int, float)):
                raise FormatError(origin, f"timing.{k}", f"expected a number of seconds, got {v!r}")
        seed = doc.get("seed")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise FormatError(origin, "seed", f"expected an integer, got {seed!r}")
        prov = doc.get("provenance", {})
        if not isinstance(prov, Mapping):
            raise FormatError(origin, "provenance", f"expected an object, got {prov!r}")
        sh = prov.get("scene_hash")
        if sh is not None and not (isinstance(sh, str) and len(sh) == 16 and all(c in "0123456789abcdef" for c in sh)):
            raise FormatError(origin, "provenance.scene_hash", f"expected 16 hex digits, got {sh!r}")
        known = {"format", "task", "target", "planner", "sequence", "predicted", "safe", "timing", "seed"}
        extra = {k: v for k, v in doc.items() if k not in known}
        return cls(task, target, planner, tuple(seq), predicted, safe, dict(timing), seed, extra)

    @classmethod
    def load(cls, path: str | Path) -> "Plan":
        """A plan file, its `safe` flag checked against its predictions (a stored session's plans
        are read as recorded, so an archive always replays)."""
        plan = cls.from_json(read_json(path), str(path))
        search = plan.extra.get("search")
        gated = search.get("plan_risk") if isinstance(search, Mapping) else None
        if gated is not None:    # a gated plan (issue 32): its claim rests on the calibrated interval
            _check_gated(plan.safe, gated, str(path))
        else:
            _check_safe(plan.safe, plan.predicted, plan.provenance, str(path))
        return plan

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json())

    def check_against(self, ids: tuple[str, ...], origin: str = "") -> None:
        """Every id in the plan must be a box of the scene it is run on."""
        known = set(ids)
        for i, b in enumerate(self.sequence):
            if b not in known:
                raise FormatError(origin, f"sequence[{i}]", f"unknown box id {b!r}; the scene has "
                                  f"{', '.join(ids) or 'no boxes'}")
