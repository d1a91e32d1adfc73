"""The console's records: what the workflow state holds and hands to its listeners.

`State` is one immutable snapshot (the page draws it); `PlanEntry` is one
planner's plan for the current capture; `Deviation` says why a run was held;
`RunLock` is the one approval that may run (docs/console.md draws the states).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, Mapping

from shelfpick.perception.scene import Scene
from shelfpick.planning.plan import Plan

if TYPE_CHECKING:   # for annotations only: importing these costs numpy, cv2 or the planner
    import numpy as np

    from shelfpick.console.workflow.look import Look
    from shelfpick.console.robot.base import RobotDriver, RobotEvent, RobotOutcome
    from shelfpick.console.workflow.verify import Verification
    from shelfpick.perception.capture import Capture
    from shelfpick.planning.step_result import StepResult

    PreviewStep = StepResult | Mapping[str, Any]   # a recorded step, or its JSON (a continued plan's)

SECONDS_PER_BOX = 12.5  # estimated robot time per removed box (pull, place, return)
AUTH_REFUSED = "wrong supervisor passphrase, or too many attempts: wait a moment and try again (recorded)"


class WorkflowError(Exception):
    """An action that is not allowed now; the message is shown to the user as is."""


@dataclass(frozen=True, eq=False)
class PlanEntry:
    """One planner's result for the current capture."""

    plan: Plan
    hash: str
    preview: tuple[PreviewStep, ...] = ()   # from Predictor.preview (recorded frames)
    shelves: tuple[Scene, ...] = ()         # the perceived Scene after each step, as predicted (verification)
    # step -> that step recorded in a sample world where it collapses (the preview shows it; h6, issue 33)
    collapse_steps: Mapping[int, Mapping[str, Any]] = field(default_factory=dict)

    @property
    def est_seconds(self) -> float:
        return SECONDS_PER_BOX * len(self.plan.sequence)

    @property
    def scene_problems(self) -> tuple[dict, ...]:
        """What the planner found does not stand as seen (plan.extra["scene_check"])."""
        return scene_problems(self.plan)


@dataclass(frozen=True, eq=False)
class State:
    """A snapshot of the console, handed to listeners; never mutated."""

    version: int = 0
    source: str = ""
    session_id: int | None = None
    frame_name: str = ""
    capture: Capture | None = None
    overlay: np.ndarray | None = None   # HxWx3 uint8 segmentation overlay
    labels: np.ndarray | None = None    # HxW uint16 perceived masks (Box.mask_label): the overlay redrawn
    matter: np.ndarray | None = None    # HxW uint16 unexplained regions (k+1 = scene.unexplained[k])
    scene: Scene | None = None          # perceived Scene
    truth: Scene | None = None          # true Scene when the source knows it (demo)
    warnings: tuple[str, ...] = ()
    target: str | None = None
    task: str | None = None
    plans: Mapping[str, PlanEntry] = field(default_factory=dict)
    capturing: bool = False
    planning: bool = False
    progress: float = 0.0
    progress_text: str = ""
    approved: str | None = None    # hash of the approved plan for this capture
    approval: Mapping[str, Any] | None = None   # plan, session, capture, who, decision id
    decisions: tuple[dict, ...] = ()
    robot: str = "idle"            # idle | running | stopping | done | stopped | failed | held
    robot_events: tuple[RobotEvent, ...] = ()
    outcome: RobotOutcome | None = None
    needs_recapture: bool = False
    scene_problems: tuple[dict, ...] = ()   # {"box", "what"}: the shelf does not stand as seen
    repairs: tuple[str, ...] = ()  # what the physics moved to make the perceived scene valid
    audit: str | None = None       # a record that could not be committed (persists until a capture is)
    recovered: tuple[str, ...] = ()  # runs found interrupted at start-up (crash, kill -9)
    verifications: tuple[Verification, ...] = ()  # the look after each step of the current run
    observed: Scene | None = None  # the shelf the last of those looks perceived (the 3D view draws it)
    deviation: Deviation | None = None  # why the last run was held (shown until the next capture)
    run_end: RunEnd | None = None  # how the last run ended (until the next capture or run)
    message: str = ""
    error: str | None = None

    def plan_by_hash(self, plan_hash: str) -> PlanEntry | None:
        """The first plan with this content hash (two planners can share one: decisions name the planner)."""
        for e in self.plans.values():
            if e.hash == plan_hash:
                return e
        return None

    @property
    def phase(self) -> str:
        """The state machine's state (docs/console.md)."""
        if self.robot in ("running", "stopping"):
            return self.robot
        if self.approved is not None:
            return "approved"
        if (self.deviation is not None and not self.capturing and not self.planning
                and set(self.plans or {}) <= {"continue"}):   # held: the only offer is to continue
            return "held"
        if self.capturing:
            return "capturing"
        if self.planning:
            return "planning"
        if self.needs_recapture:
            return "finished"
        if self.plans:
            return "planned"
        return "captured" if self.scene is not None else "empty"


RobotFactory = Callable[[Scene | None, int], "RobotDriver"]   # (truth, seed) -> a driver for one run
Listener = Callable[[State], None]


@dataclass(frozen=True, eq=False)
class Deviation:
    """A run held because the shelf did not do what was predicted: what differed, and where.

    `predicted` is the shelf the plan predicted after `verification.step`
    (ids of the held plan's capture); the observed shelf is the new capture
    the workflow made current (session `session`), held from `held_session`.
    """

    verification: Verification
    predicted: Scene | None        # None: the plan had no prediction for that step
    plan: str                      # hash of the held plan
    held_session: int
    session: int | None            # the verification capture's session (plan again from it)


@dataclass(frozen=True, eq=False)
class RunEnd:
    """How a run ended, for the page: the plan it ran is no longer up for review, this says what
    became of it. One object per ended run (the page tells runs apart by identity)."""

    planner: str
    plan: str                      # content hash of the plan that ran
    sequence: tuple[str, ...]
    status: str                    # done | held | stopped | failed (State.robot at the end)
    completed: tuple[str, ...] = ()
    step: int | None = None        # held: the step whose look held it; else the first step not done
    box: str | None = None         # that step's box
    stopped_by: str | None = None


@dataclass(eq=False)
class RunLock:
    """The run lock: one approval of one plan for one capture, until its run ends."""

    plan_hash: str
    entry: PlanEntry
    session_id: int
    gen: int
    who: str
    stop: threading.Event = field(default_factory=threading.Event)
    planner: str = ""                # whose plan was approved (two planners can find one sequence)
    decision_id: int | None = None   # set once the approval is committed
    started: bool = False            # execute() took it
    thread: threading.Thread | None = None
    stopped_by: str | None = None
    audit_failed: str | None = None  # a robot event that could not be committed: the run was stopped
    scene: Scene | None = None       # the perceived and (demo) true scene of the approved capture
    truth: Scene | None = None
    robot_run: str = ""              # the run id sent to the robot (keys its "already done"); recorded
    verifications: list[Verification] = field(default_factory=list)   # one per verified step
    held: Look | None = None         # the look that held the robot (it had a frame and a perception)


def scene_problems(plan: Plan) -> tuple[dict, ...]:
    """plan.extra["scene_check"]["problems"] when the shelf does not stand as seen, else ()."""
    check = (plan.extra or {}).get("scene_check") or {}
    if not isinstance(check, Mapping) or check.get("stands_as_seen", True):
        return ()
    probs = check.get("problems") or [{"box": None, "what": "does not stand as seen"}]
    return tuple({"box": p.get("box"), "what": str(p.get("what", ""))} for p in probs if isinstance(p, Mapping))


def problem_text(p: Mapping[str, Any]) -> str:
    return (f"box {p['box']}" if p.get("box") else "the scene") + f" {p.get('what', '')}".rstrip()



__all__ = ["SECONDS_PER_BOX", "AUTH_REFUSED", "WorkflowError", "PlanEntry", "State", "Deviation", "RunEnd", "RunLock",
           "RobotFactory", "Listener", "scene_problems", "problem_text"]
