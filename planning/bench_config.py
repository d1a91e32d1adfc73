"""What a benchmark run is asked to do (`BenchConfig`) and the truth its plans are judged on
(`TruthModel`): plain settings that the run (`planning.bench`) and its report
(`planning.bench_report`) both read, kept below both.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

from shelfpick.planning.uncertainty import Uncertainty

__all__ = ["BenchConfig", "TruthModel"]


@dataclass(frozen=True)
class TruthModel:
    """How the bench's truth differs from what the planner is given and assumes (docs/bench.md).

    The planner sees front faces only (depth unknown, no masses) with `noise` m of
    perception error on each front-face centre and size; the plan runs on the true
    shelf with true masses and a physics drawn per scene: another friction, a pull of
    another speed and force limit, without the planner's lift.
    """

    noise: float = 0.01                                   # m, sd per axis of a front face's centre and size
    mass: tuple[float, float] = (0.3, 5.0)                # kg per box (kept where the scene gives one)
    friction: tuple[float, float] = (0.5, 0.9)
    pull_speed: tuple[float, float] = (0.15, 0.35)        # m/s (the planner assumes 0.5)
    pull_force: tuple[float, float] = (100.0, 200.0)      # N
    pull_lift: float = 0.0                                # m: a drag, no lift
    # with no lift: False, the box rides on its support, its height free (the bench's truth since
    # the start, harsher than the worlds' "drag"); True, the arm holds its height as the worlds'
    # "drag" does (a stiff suction arm pulling straight out)
    pull_hold: bool = False
    stand_tolerance: float = 0.015                        # m a true box may move while the truth settles
    draws: int = 6                                        # truth draws tried before a scene is given up

    def to_json(self) -> dict:
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


@dataclass(frozen=True)
class BenchConfig:
    """One run of the benchmark: the planners compared, the sample worlds and seed, the truth."""

    planners: tuple[str, ...] = ("physics", "heuristic")
    samples: int = 10
    seed: int = 0
    exhaustive_max_boxes: int = 8
    robot_time: float = 12.5
    # False: every target gets a fresh Predictor and its build counts in plan_s, which is
    # what an operator waits for. True: one Predictor per scene shared by all its targets
    # (faster throughput; later targets reuse cached trials, so plan_s understates latency).
    shared_predictor: bool = False
    # the truth plans are judged on: a perturbed one (default), or None for the planner's own
    # world (depths hidden, nothing else differs: the old bench, which flatters the planner)
    truth: TruthModel | None = TruthModel()
    # the planner's prior that a face of a stock box type has that type's depth (Uncertainty.catalogue)
    catalogue: bool = True

    def model(self) -> Uncertainty:
        """What the planner draws per sample world."""
        return Uncertainty() if self.catalogue else Uncertainty(catalogue=())

    def to_json(self) -> dict:
        d = asdict(self)
        d["planners"] = list(self.planners)
        d["truth"] = None if self.truth is None else self.truth.to_json()
        return d
