"""Robot drivers: what executes an approved plan, step by step, and reports what really happened.

Two drivers meet the `RobotDriver` protocol:

- `SimRobot` ("sim"): executes on the TRUE scene (the demo source knows it)
  in its own `ShelfSim`, one `ShelfSim.remove` per step. It reports what the
  physics did, which may differ from the planner's prediction (the planner
  only saw front faces and guessed the depths). Box ids of the perceived
  scene are matched to the true boxes by their front-face centres, as a real
  robot would find a box by where its grasp point is.
- `TcpRobot` ("tcp://HOST:PORT", console/robot_tcp.py): line-delimited JSON
  to a robot-side controller (docs/robot-protocol.md).

Both honour the `stop` event between steps, never re-send a step that a
previous run of the same plan (same content hash) completed, and stop the
sequence on the first error or collapse: the shelf is no longer what the
plan was made for, so a new capture and plan are needed.
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol
from urllib.parse import parse_qs, urlsplit

from perception.errors import ShelfpickError
from perception.scene import Box, Scene
from planning.plan import Plan

log = logging.getLogger(__name__)

EVENT_KINDS = ("ack", "done", "error", "aborted", "disconnected")
REPLAN = "a new capture and plan are needed"


class RobotError(ShelfpickError):
    """A robot spec, transform or connection the user has to fix."""


@dataclass(frozen=True)
class RobotEvent:
    """One thing the robot reported: `ack` (step accepted), `done`, `error`, `aborted`, `disconnected`."""

    kind: str
    step: int | None = None
    box: str | None = None
    detail: Mapping[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict:
        return {"kind": self.kind, "step": self.step, "box": self.box, "detail": dict(self.detail)}


@dataclass(frozen=True)
class RobotOutcome:
    """How a plan run ended.

    `completed`: boxes of this plan the robot has taken out (including those
    of an earlier run of the same plan hash, which were not re-sent), in plan
    order. `steps`: one dict per plan step: `step`, `box`, `status`
    (done | skipped | error | aborted | unknown | not_sent) and `detail`.
    `ok`: every step done, nothing collapsed, no error.
    """

    completed: tuple[str, ...]
    ok: bool
    error: str | None
    steps: tuple[dict, ...]
    plan: str | None = None
    needs_replan: bool = False

    def to_json(self) -> dict:
        return {"plan": self.plan, "completed": list(self.completed), "ok": self.ok, "error": self.error,
                "needs_replan": self.needs_replan, "steps": [dict(s) for s in self.steps]}


class RobotDriver(Protocol):
    name: str

    def execute(self, plan: Plan, scene: Scene, on_event: Callable[[RobotEvent], None],
                stop: threading.Event) -> RobotOutcome: ...


# --------------------------------------------------------------------------
class StepHistory:
    """Steps each plan hash has completed (and steps whose outcome is unknown), per robot endpoint.

    Kept process-wide so that a fresh driver object for the same robot (the
    console builds one per run) still never re-sends a completed step.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._done: dict[tuple[str, str], dict[int, str]] = {}
        self._unknown: dict[tuple[str, str], dict[int, str]] = {}

    def completed(self, endpoint: str, plan_hash: str) -> dict[int, str]:
        with self._lock:
            return dict(self._done.get((endpoint, plan_hash), {}))

    def unknown(self, endpoint: str, plan_hash: str) -> dict[int, str]:
        with self._lock:
            return dict(self._unknown.get((endpoint, plan_hash), {}))

    def mark_done(self, endpoint: str, plan_hash: str, step: int, box: str) -> None:
        with self._lock:
            self._done.setdefault((endpoint, plan_hash), {})[step] = box
            self._unknown.get((endpoint, plan_hash), {}).pop(step, None)

    def mark_unknown(self, endpoint: str, plan_hash: str, step: int, box: str) -> None:
        with self._lock:
            self._unknown.setdefault((endpoint, plan_hash), {})[step] = box

    def settle(self, endpoint: str, plan_hash: str, step: int) -> None:
        """The robot reported how an in-flight step ended (failed or aborted): no longer unknown."""
        with self._lock:
            self._unknown.get((endpoint, plan_hash), {}).pop(step, None)

    def forget(self, endpoint: str | None = None) -> None:
        """Drop the history (tests; or a robot whose shelf was reset by hand)."""
        with self._lock:
            for d in (self._done, self._unknown):
                for k in [k for k in d if endpoint is None or k[0] == endpoint]:
                    del d[k]


HISTORY = StepHistory()


def emit(on_event: Callable[[RobotEvent], None], ev: RobotEvent) -> None:
    """Report an event; a failing listener (UI, database) must never leave the robot mid-plan."""
    try:
        on_event(ev)
    except Exception:  # noqa: BLE001
        log.exception("robot event listener failed on %s", ev)


def finish(plan: Plan, plan_hash: str, statuses: dict[int, dict], error: str | None,
           history: StepHistory, endpoint: str) -> RobotOutcome:
    """Assemble the outcome: per step status, completed boxes in plan order, replan flag."""
    done = history.completed(endpoint, plan_hash)
    steps = []
    for i, box in enumerate(plan.sequence):
        s = statuses.get(i) or {"step": i, "box": box, "status": "not_sent", "detail": {}}
        steps.append(s)
    completed = tuple(plan.sequence[i] for i in sorted(done))
    ok = error is None and len(done) == len(plan.sequence)
    if not ok and error is None:
        error = "the plan did not complete"
    if not ok and REPLAN not in (error or ""):
        error = f"{error}; {REPLAN}"
    return RobotOutcome(completed, ok, error, tuple(steps), plan_hash, needs_replan=not ok)


# --------------------------------------------------------------------------
def match_boxes(perceived: Scene, truth: Scene, present: Mapping[str, Box] | None = None,
                tol: float = 0.08) -> dict[str, str]:
    """Perceived id -> true id, by nearest front-face centre (greedy, closest pairs first).

    A robot finds a box where the camera saw its front face, not by a name;
    the true scene's ids need not agree with perception's.
    """
    cands = present if present is not None else {b.id: b for b in truth.boxes}
    pairs = []
    for p in perceived.boxes:
        fp = p.front_center
        for tid, t in cands.items():
            ft = t.front_center
            d = math.dist(fp, ft)
            if d <= tol:
                pairs.append((d, p.id != tid, p.id, tid))
    pairs.sort()
    out: dict[str, str] = {}
    used: set[str] = set()
    for _, _, pid, tid in pairs:
        if pid not in out and tid not in used:
            out[pid] = tid
            used.add(tid)
    return out


class SimRobot:
    """Executes a plan on the true scene in its own physics simulation (one ShelfSim per robot).

    The world persists between runs of the same robot object: boxes taken
    out stay out, collapsed boxes stay where they fell.
    """

    def __init__(self, truth: Scene | None = None, seed: int = 0, config: Any = None,
                 step_delay: float = 0.0, match_tol: float = 0.08) -> None:
        self.name = "sim"
        self.truth = truth
        self.seed = int(seed)
        self.config = config
        self.step_delay = float(step_delay)
        self.match_tol = float(match_tol)
        self._sim: Any = None
        self._world_scene: Scene | None = None
        self._lock = threading.Lock()
        self._history = StepHistory()
        self._endpoint = f"sim:{id(self)}"

    def set_truth(self, truth: Scene | None) -> None:
        """A new shelf in front of the robot (a new demo capture): rebuild the world."""
        with self._lock:
            self.close_sim()
            self.truth = truth
            self._history.forget()

    def close_sim(self) -> None:
        if self._sim is not None:
            self._sim.close()
            self._sim = None

    def close(self) -> None:
        with self._lock:
            self.close_sim()

    def _world(self, scene: Scene) -> Any:
        if self._sim is None:
            from planning.sim import ShelfSim

            self._world_scene = self.truth if self.truth is not None else scene
            self._sim = ShelfSim(self._world_scene, self.config)
        return self._sim

    def world(self) -> Scene | None:
        """The true scene as it stands now (present boxes at their current poses)."""
        with self._lock:
            if self._sim is None:
                return self.truth
            poses = self._sim.poses()
            base = {b.id: b for b in self._sim.scene.boxes}
            from dataclasses import replace

            return self._sim.scene.with_boxes(
                replace(base[i], position=tuple(p), orientation=tuple(q)) for i, (p, q) in poses.items())

    def _present_boxes(self) -> dict[str, Box]:
        from dataclasses import replace

        base = {b.id: b for b in self._sim.scene.boxes}
        return {i: replace(base[i], position=tuple(p), orientation=tuple(q))
                for i, (p, q) in self._sim.poses().items()}

    def execute(self, plan: Plan, scene: Scene, on_event: Callable[[RobotEvent], None],
                stop: threading.Event) -> RobotOutcome:
        h = plan.content_hash()
        statuses: dict[int, dict] = {}
        error: str | None = None
        with self._lock:
            try:
                sim = self._world(scene)
            except ShelfpickError as exc:
                emit(on_event, RobotEvent("error", None, None, {"code": "WORLD", "message": str(exc)}))
                return finish(plan, h, statuses, f"the simulated robot cannot build its world: {exc}",
                              self._history, self._endpoint)
            note = {} if self.truth is not None else {"note": "no ground truth: executing on the perceived scene"}
            earlier = self._history.completed(self._endpoint, h)
            for i, box in enumerate(plan.sequence):
                if i in earlier:
                    statuses[i] = {"step": i, "box": box, "status": "skipped",
                                   "detail": {"reason": "completed by an earlier run of this plan; not re-sent"}}
                    continue
                if stop.is_set():
                    emit(on_event, RobotEvent("aborted", i, box, {"reason": "stop requested"}))
                    statuses[i] = {"step": i, "box": box, "status": "aborted", "detail": {}}
                    error = f"stopped before step {i + 1} ({box})"
                    break
                present = self._present_boxes()
                mapping = match_boxes(scene, self._world_scene, present, self.match_tol) \
                    if box in scene.ids else {}
                if box not in mapping and box in present and self.truth is None:
                    mapping[box] = box
                tid = mapping.get(box)
                if tid is None:
                    detail = {"code": "NO_BOX_AT_GRASP",
                              "message": f"no box on the real shelf where {box!r} was seen"}
                    emit(on_event, RobotEvent("error", i, box, detail))
                    statuses[i] = {"step": i, "box": box, "status": "error", "detail": detail}
                    error = f"step {i + 1} ({box}): {detail['message']}"
                    break
                emit(on_event, RobotEvent("ack", i, box, {"true_box": tid, **note}))
                t0 = time.monotonic()
                res = sim.remove(tid, seed=self.seed * 1000 + i)
                wait = self.step_delay - (time.monotonic() - t0)
                if wait > 0:
                    stop.wait(wait)
                reverse = {t: p for p, t in match_boxes(scene, self._world_scene, {
                    b.id: b for b in self._world_scene.boxes}, self.match_tol).items()}
                detail = res.to_json()
                detail.pop("box", None)
                detail["true_box"] = tid
                detail["collapsed_ids"] = [reverse.get(b, b) for b in res.collapsed]
                detail["collided_ids"] = [reverse.get(b, b) for b in res.collided]
                if not res.extracted:
                    detail["code"] = "PICK_FAILED"
                    detail["message"] = f"box {box!r} did not come out ({res.note or 'stuck'})"
                    emit(on_event, RobotEvent("error", i, box, detail))
                    statuses[i] = {"step": i, "box": box, "status": "error", "detail": detail}
                    error = f"step {i + 1} ({box}): {detail['message']}"
                    break
                self._history.mark_done(self._endpoint, h, i, box)
                emit(on_event, RobotEvent("done", i, box, detail))
                statuses[i] = {"step": i, "box": box, "status": "done", "detail": detail}
                if res.collapsed:
                    msg = (f"step {i + 1} ({box}): boxes collapsed: {', '.join(detail['collapsed_ids'])}")
                    emit(on_event, RobotEvent("error", i, box, {"code": "COLLAPSE", "message": msg,
                                                                 "collapsed": detail["collapsed_ids"]}))
                    error = msg
                    break
        return finish(plan, h, statuses, error, self._history, self._endpoint)


# --------------------------------------------------------------------------
def _query_float(q: dict[str, list[str]], key: str, spec: str, default: float) -> float:
    if key not in q:
        return default
    try:
        v = float(q[key][-1])
    except ValueError:
        raise RobotError(f"robot spec {spec!r}: {key}: expected a number, got {q[key][-1]!r}") from None
    if not math.isfinite(v) or v < 0:
        raise RobotError(f"robot spec {spec!r}: {key}: expected a number >= 0, got {q[key][-1]!r}")
    return v


def open_robot(spec: str, truth: Scene | None = None, seed: int = 0) -> RobotDriver:
    """`sim[?delay=S]` or `tcp://HOST:PORT[?transform=FILE|position=..&orientation=..&timeouts]`."""
    parts = urlsplit(spec.strip())
    if spec.strip().split("?")[0] == "sim":
        q = parse_qs(spec.split("?", 1)[1]) if "?" in spec else {}
        unknown = set(q) - {"delay", "seed"}
        if unknown:
            raise RobotError(f"robot spec {spec!r}: unknown option {sorted(unknown)[0]!r} (sim takes delay, seed)")
        s = int(_query_float(q, "seed", spec, seed))
        return SimRobot(truth, seed=s, step_delay=_query_float(q, "delay", spec, 0.0))
    if parts.scheme == "tcp":
        from console.robot_tcp import TcpRobot

        return TcpRobot.from_spec(spec)
    raise RobotError(f"robot spec {spec!r}: expected 'sim' or 'tcp://HOST:PORT'")


def __getattr__(name: str) -> Any:  # `from console.robot import TcpRobot` as ARCHITECTURE.md lists it
    if name == "TcpRobot":
        from console.robot_tcp import TcpRobot

        return TcpRobot
    raise AttributeError(name)


__all__ = ["RobotEvent", "RobotOutcome", "RobotDriver", "RobotError", "SimRobot", "TcpRobot",
           "StepHistory", "HISTORY", "match_boxes", "open_robot", "REPLAN"]
