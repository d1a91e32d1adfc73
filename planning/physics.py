"""Physics parameters of the shelf simulation, in one frozen dataclass.

The defaults are the method's (gravity, friction, a box density of 1 kg/m^3)
plus the numbers this implementation chose for speed and robustness; each
choice and its measurement is written up in docs/physics.md.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass, fields, replace
from typing import Any, Mapping

from shelfpick.perception.errors import FormatError


@dataclass(frozen=True)
class PhysicsConfig:
    """Everything the simulation needs to know besides the scene."""

    # the method's world
    gravity: float = 9.81               # m/s^2
    lateral_friction: float = 0.75
    spinning_friction: float = 0.01
    density: float = 1.0                # kg/m^3 (the method's); a box's `mass` overrides
    # integration
    time_step: float = 1.0 / 120.0      # s; see docs/physics.md for the fine-step comparison
    solver_iterations: int = 50
    prediction_solver_iterations: int = 50  # the Predictor's sample worlds; 30 was tried and dropped:
                                            # spurious collapses in 30-box shelves (docs/speed.md)
    # suction pull along -y
    pull_speed: float = 0.5             # m/s, reached after `pull_ramp`
    pull_ramp: float = 0.05             # s of linear speed ramp (no infinite jerk)
    pull_force: float = 200.0           # N, absolute force limit of the suction drive ...
    pull_force_weights: float = 20.0    # ... and at most this many times the pulled box's weight
    pull_margin: float = 0.02           # m past the shelf front before the box counts as out
    pull_lift: float = 0.006            # m the gripper lifts the box before pulling (capped by the
                                        # free space above it; 0 = drag it on its support)
    lift_time: float = 0.05             # s the lift takes
    pull_hold: bool = False             # with no lift: the arm holds the box's height instead of
                                        # letting it ride on its support
    pull_turn: bool = False             # a held box (lift, `pull_hold`) may turn about its centre, which
                                        # the arm holds (a cup soft in rotation); off: the arm holds the
                                        # face and its orientation (docs/results/risk-gate.md, session 47)
    # with `hold_spring` the held height (lift, or `pull_hold`) is a spring on the box's height whose
    # force is bounded by what a compliant suction cup on a vertical face can exert: it carries the
    # box (up to `hold_up_weights` of its weight) but presses it down at most `hold_down_weights`.
    # Off by default: a rigid hold carries 60 % of a dragged box's weight and presses with up to 10
    # weights once the box below tips into it, but the spring did not make the gate better on our
    # bench (docs/physics.md, "Removing a box"; docs/results/risk-gate.md)
    hold_spring: bool = False
    hold_carry: float = 0.0             # with `hold_spring`: the share of a dragged box's weight the drive
                                        # carries (a lifted one's: all of it)
    hold_stiffness: float = 1000.0      # 1/s^2 per kg of the box (about 5 Hz)
    hold_damping: float = 45.0          # 1/s per kg
    hold_up_weights: float = 1.5        # most upward force, in weights of the pulled box
    hold_down_weights: float = 0.5      # most downward force, in weights of the pulled box
    pull_timeout: float = 3.0           # s; a box that does not come out by then is stuck
    disturbance: float = 0.002          # m, amplitude of the seeded lateral vibration (x)
    disturbance_force: float = 0.1      # vertical vibration force, in weights of the pulled box
    disturbance_period: float = 0.05    # s between vibration set points
    early_clear: bool = True            # park the box once nothing leans on it any more ...
    clear_time: float = 0.02            # ... for this long (s)
    gripper_size: tuple[float, float, float] = (0.06, 0.04, 0.06)  # suction cup body, m
    gripper_gap: float = 1e-3           # m between the cup and the face it holds
    disturbance_smoothing: float = 0.3  # share of the way to the next vibration set point per step
    contact_slop: float = 1e-3          # m: a contact point this far apart still touches
    support_normal: float = 0.5         # |normal z| above this: a contact that carries weight
    engage_force_weights: float = 0.05  # normal force (in weights of the pulled box) that still drags it
    record_fps: float = 30.0            # frames per second of sim time in a recorded pull
    lift_clearance: float = 0.002       # m kept free above a lifted box
    lift_footprint_shrink: float = 0.003  # m a box above must overlap the lifted one's footprint to bound it
    # settling
    settle_time: float = 1.0            # s, most time the rest gets to settle after a step
    initial_settle_time: float = 3.0    # s, most time a fresh scene gets to come to rest
    rest_velocity: float = 0.02         # m/s, below this a box is at rest
    rest_angular_velocity: float = 0.3  # rad/s
    rest_window: float = 0.1            # s a scene must stay at rest to count as settled
    monitor_every: int = 2              # steps between looks at the other boxes during a trial
    # locality (docs/speed.md): a prediction trial simulates only the pulled box's
    # neighbourhood (boxes within `local_margin` of it, plus everything stacked on
    # those); the other boxes stand in as static copies of themselves
    prediction_local: bool = True       # the Predictor's sample worlds use it; execution never does
    local_margin: float = 0.02          # m between bounding boxes that still counts as near
    support_overlap: float = 0.005      # m two footprints overlap when one box stands on another ...
    support_tilt: float = 0.03          # ... whose top may be this far above the upper one's bottom (tilt)
    # verdicts
    collapse_displacement: float = 0.02     # m from the step's start to its end
    collapse_rotation: float = 10.0         # degrees from the step's start to its end
    collapse_peak_displacement: float = 0.05  # m at any moment (with `peak_tipping`: slid level,
                                              # turned < collapse_rotation / 2)
    collapse_peak_rotation: float = 20.0      # degrees at any moment, or with `peak_tipping` the
                                              # box's tipping angle when larger
    peak_tipping: bool = False              # a box that tips less than its tipping angle and falls
                                              # back is judged at the end of the step (off: see
                                              # docs/physics.md "Verdicts")
    collapse_velocity: float = 0.6          # m/s
    collapse_angular_velocity: float = 6.0  # rad/s
    onset_displacement: float = 0.003       # m: "started moving" (orders the collapsed boxes)
    onset_velocity: float = 0.1             # m/s: also "started moving"
    collision_threshold: float = 0.005      # m a touched neighbour must move to count
    # scene repair
    repair_tolerance: float = 0.02      # m of overlap repaired; more is refused
    repair_min_overlap: float = 0.003   # m; shallower overlaps are resting contact, left to Bullet
    settle_report: float = 0.005        # m a box must move while a new scene settles to be reported
    repair_rounds: int = 30             # passes of pushing overlapping boxes apart
    repair_push: float = 2e-4           # m pushed past the overlap each pass
    edge_perch: float = 0.0             # m: a box resting on a strip of another's top edge this narrow
                                        # is moved off it (a carton's edge is rounded); 0 = off, the
                                        # default: 0.005 was neutral on our bench (docs/physics.md)
    fallen_below: float = 0.02          # m below the shelf floor: a box is off the shelf
    # a perceived shelf is measured to about 1 cm per face (docs/physics.md): its sample worlds
    # repair overlaps up to `prediction_repair_tolerance`, and a box that then moves more than
    # `stand_tolerance` sideways or up (or turns more than `stand_rotation`) while settling did not
    # stand as seen; straight down it may drop up to `stand_drop` onto what is below it: the heights
    # of a stack's faces add up their errors (1 cm each: 3-6 cm at the top of a 1 cm-noise stack),
    # and a gap that size under a box is a measurement, not a box that nothing holds
    prediction_repair_tolerance: float = 0.05   # m
    stand_tolerance: float = 0.03       # m
    stand_drop: float = 0.06            # m
    stand_rotation: float = 8.0         # degrees
    stand_nudge: float = 0.5            # rad/s of the knock a standing shelf must survive (ShelfSim.nudge)
    off_shelf_front: float = 0.3        # m in front of the shelf: a settled box there fell off it
    # shelf model
    shelf_top: bool = True
    wall_thickness: float = 0.05
    ground_drop: float = 0.8            # m from the shelf floor down to the room floor
    min_sample_depth: float = 0.15      # m, lower bound of a drawn box depth (docs/physics.md)

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            if isinstance(v, bool) or f.name == "gripper_size":
                continue
            if not isinstance(v, (int, float)) or v != v or (v < 0) or (v == 0 and f.name in _POSITIVE):
                raise FormatError("physics config", f.name, f"expected a positive number, got {v!r}")

    @property
    def steps_per_second(self) -> float:
        return 1.0 / self.time_step

    def for_prediction(self) -> "PhysicsConfig":
        """The settings of the Predictor's sample worlds (coarser where accuracy allows)."""
        return replace(self, solver_iterations=self.prediction_solver_iterations,
                       repair_tolerance=max(self.repair_tolerance, self.prediction_repair_tolerance))

    def replace(self, **changes: Any) -> "PhysicsConfig":
        return replace(self, **changes)

    def to_json(self) -> dict:
        doc = asdict(self)
        doc["gripper_size"] = list(self.gripper_size)
        return doc

    @classmethod
    def from_json(cls, doc: Mapping[str, Any], origin: str = "") -> "PhysicsConfig":
        known = {f.name for f in fields(cls)}
        if not isinstance(doc, Mapping):
            raise FormatError(origin, "physics", f"expected an object, got {type(doc).__name__}")
        for k in doc:
            if k not in known:
                raise FormatError(origin, f"physics.{k}", "unknown parameter")
        kw = dict(doc)
        if "gripper_size" in kw:
            kw["gripper_size"] = tuple(kw["gripper_size"])
        return cls(**kw)


_POSITIVE = {"gravity", "density", "time_step", "solver_iterations", "prediction_solver_iterations", "pull_speed", "pull_force",
             "pull_force_weights", "pull_timeout", "settle_time", "initial_settle_time", "rest_velocity",
             "rest_angular_velocity", "collapse_displacement", "collapse_rotation",
             "collapse_velocity", "collapse_angular_velocity", "collapse_peak_displacement",
             "collapse_peak_rotation", "repair_tolerance", "stand_tolerance", "stand_drop", "stand_rotation",
             "wall_thickness", "min_sample_depth", "record_fps", "repair_rounds"}
