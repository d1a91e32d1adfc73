"""What every robot driver shares: events, outcomes, the step history, spec options.

Kept apart from the drivers so that `console/robot/drivers.py` (the sim driver and
`open_robot`) and `console/robot/tcp.py` (the TCP driver) both import it and
neither imports the other at module level.
"""
from __future__ import annotations

import logging
import math
import secrets
import threading
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping, Protocol

from shelfpick.perception.errors import ShelfpickError
from shelfpick.perception.scene import Scene
from shelfpick.planning.plan import Plan

log = logging.getLogger("shelfpick.console.robot.drivers")

EVENT_KINDS = ("ack", "done", "error", "aborted", "disconnected", "note")  # note: no step, no fault
REPLAN = "a new capture and plan are needed"


class RobotError(ShelfpickError):
    """A robot spec, transform or connection the user has to fix."""


@dataclass(frozen=True)
class RobotEvent:
    """One thing the robot reported: `ack` (step accepted), `done`, `error`, `aborted`, `disconnected`,
    or a `note` (`detail.message`: something the operator must read that is no step's outcome)."""

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
    (done | skipped | error | aborted | unknown | unacknowledged | not_sent)
    and `detail`.
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

    Owned by whoever opens the robot and handed to the driver: the console's
    workflow makes one per run, seeded from the session database (the
    persistent "never re-send a step", keyed by capture and plan), so every
    reconnect within that run sees what the run already did; a driver made
    without one owns its own (its reconnects share it, another driver's do not).
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


def emit(on_event: Callable[[RobotEvent], None], ev: RobotEvent) -> None:
    """Report an event; a failing listener (UI, database) must never leave the robot mid-plan."""
    try:
        on_event(ev)
    except Exception:  # noqa: BLE001
        log.exception("robot event listener failed on %s", ev)


def record_before_sending(record_sent: Callable[[int, str], None] | None, statuses: dict[int, dict],
                          step: int, box: str) -> str | None:
    """Have the console commit that `step` goes out, before it does; why not (it stays unsent), or None."""
    if record_sent is None:
        return None
    try:
        record_sent(step, box)
    except Exception as exc:  # noqa: BLE001 - StoreError, WorkflowError alike: not on record, not sent
        why = f"its `sent` record could not be committed ({exc})"
        statuses[step] = {"step": step, "box": box, "status": "not_sent", "detail": {"reason": why}}
        return f"step {step + 1} ({box}) was not sent: {why}"
    return None


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


def new_run_id(prefix: str = "") -> str:
    """A run id no other run shares: `prefix` (the console puts its session there) + 96 random bits.

    Sent to a TCP robot with every step (it keys "already done" by it) and
    recorded with the run's start. An identity, not a draw that changes any
    result, so it takes no seed (like the store's owner token).
    """
    return f"{prefix}{secrets.token_hex(12)}"


# --------------------------------------------------------------------------
def query_float(q: dict[str, list[str]], key: str, spec: str, default: float) -> float:
    """A number option of a robot spec's query string within the cell file's bounds for it
    (console.cell.ROBOT_NUMBERS: one table for both), or `default`."""
    from shelfpick.console.cell import ROBOT_NUMBERS

    if key not in q:
        return default
    try:
        v = float(q[key][-1])
    except ValueError:
        raise RobotError(f"robot spec {spec!r}: {key}: expected a number, got {q[key][-1]!r}") from None
    lo, hi = ROBOT_NUMBERS.get(key, (0.0, math.inf))
    if not math.isfinite(v) or not lo <= v <= hi:
        raise RobotError(f"robot spec {spec!r}: {key}: expected a number in [{lo:g}, {hi:g}], got {q[key][-1]!r}")
    return v


__all__ = ["EVENT_KINDS", "REPLAN", "RobotError", "RobotEvent", "RobotOutcome", "RobotDriver", "StepHistory",
           "emit", "finish", "new_run_id", "query_float", "record_before_sending"]
