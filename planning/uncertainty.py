"""What the camera cannot know, and pure functions that draw one plausible shelf from it.

A camera sees front faces. It does not see a box's depth or mass, the friction
of its cardboard, its own error on each face (about 1 cm), or how exactly the
robot's suction pull will go (lift or drag, speed, force limit). A prediction
is only as good as the worst plausible draw of all of these, so every sample
world is one such draw: `draw_world(scene, seed, k, model) -> (Scene, PhysicsConfig)`,
a pure function of its arguments (same seed, same world).

The ranges are written up, with how they were chosen, in docs/physics.md
("What the camera cannot know").
"""
from __future__ import annotations

import math
import random
from dataclasses import dataclass, replace

from perception.scene import Box, Scene, quat_to_matrix
from planning.physics import PhysicsConfig


PULL_MODES = ("lift", "drag", "ride")


@dataclass(frozen=True)
class Uncertainty:
    """Ranges of the quantities a prediction draws per sample world.

    Every range is (low, high); a range with low == high pins the quantity.
    `depth_known` boxes keep their depth; boxes with a `mass` keep it.
    """

    mass: tuple[float, float] = (0.3, 5.0)          # kg per box, log-uniform (an empty carton to books)
    friction: tuple[float, float] = (0.6, 0.9)      # cardboard on cardboard/board, one per world
    face_error: float = 0.005                        # m, half-range of each face's centre error (x, z)
    pull_speed: tuple[float, float] = (0.2, 0.5)    # m/s
    pull_force: tuple[float, float] = (100.0, 200.0)  # N, the suction drive's force limit
    # how the arm pulls: "lift" (a few mm up, then straight out), "drag" (straight out on its
    # support, the arm holding the height), "ride" (on its support, height free: the method's
    # original drive, kept for comparisons); one mode per world, drawn evenly
    pull_modes: tuple[str, ...] = ("lift", "drag")

    @classmethod
    def none(cls) -> "Uncertainty":
        """Only the depth is drawn (the method's original model): for comparisons and tests."""
        return cls(mass=(0.0, 0.0), friction=(0.0, 0.0), face_error=0.0, pull_speed=(0.0, 0.0),
                   pull_force=(0.0, 0.0), pull_modes=())

    @property
    def draws_mass(self) -> bool:
        return self.mass[1] > 0

    def to_json(self) -> dict:
        return {"mass_kg": list(self.mass), "friction": list(self.friction), "face_error_m": self.face_error,
                "pull_speed_m_s": list(self.pull_speed), "pull_force_n": list(self.pull_force),
                "pull_modes": list(self.pull_modes)}


def _rng(seed: int, k: int, what: str) -> random.Random:
    return random.Random(f"shelfpick-draw:{int(seed)}:{int(k)}:{what}")


def _uniform(rng: random.Random, lo_hi: tuple[float, float]) -> float:
    lo, hi = lo_hi
    return lo if hi <= lo else rng.uniform(lo, hi)


def draw_config(config: PhysicsConfig, seed: int, k: int, model: Uncertainty) -> PhysicsConfig:
    """The physics of draw `k`: friction and the pull (lift or drag, speed, force limit)."""
    rng = _rng(seed, k, "physics")
    changes: dict = {}
    if model.friction[1] > 0:
        changes["lateral_friction"] = _uniform(rng, model.friction)
    if model.pull_speed[1] > 0:
        changes["pull_speed"] = _uniform(rng, model.pull_speed)
    if model.pull_force[1] > 0:
        changes["pull_force"] = _uniform(rng, model.pull_force)
        # the force limit is the drive's, not a multiple of a weight nobody knows
        changes["pull_force_weights"] = 1e6
    if model.pull_modes:
        mode = model.pull_modes[rng.randrange(len(model.pull_modes))]
        if mode not in PULL_MODES:
            raise ValueError(f"unknown pull mode {mode!r}; expected one of {', '.join(PULL_MODES)}")
        changes["pull_lift"] = config.pull_lift if mode == "lift" else 0.0
        changes["pull_hold"] = mode != "ride"
    return config.replace(**changes) if changes else config


def depth_of(box: Box, depth: float) -> Box:
    """`box` with `depth`, its front face kept."""
    return box.with_depth(depth)


def draw_scene(scene: Scene, seed: int, k: int, model: Uncertainty,
               ranges: dict[str, tuple[float, float]], reach: float = 1.0) -> Scene:
    """The shelf of draw `k`: each unknown depth uniform in its range (shrunk by `reach`),
    each unknown mass log-uniform, each face moved by up to `face_error` in x and z.

    `ranges` are the depth ranges of the boxes with unknown depth (`predict.depth_ranges`).
    The depth draws use the same stream as the method's original sampler, so with
    `Uncertainty.none()` a draw is exactly the old depth sample.
    """
    depth_rng = random.Random(f"shelfpick-depth:{int(seed)}:{int(k)}")
    other = _rng(seed, k, "boxes")
    out = []
    for b in scene.boxes:
        if not b.depth_known:
            lo, hi = ranges[b.id]
            b = depth_of(b, depth_rng.uniform(lo, lo + (hi - lo) * reach))
        if model.face_error > 0:
            dx = other.uniform(-model.face_error, model.face_error)
            dz = other.uniform(-model.face_error, model.face_error)
            r = quat_to_matrix(b.orientation)   # move the face in its own plane
            shift = tuple(r[i][0] * dx + r[i][2] * dz for i in range(3))
            b = replace(b, position=tuple(b.position[i] + shift[i] for i in range(3)))
        if model.draws_mass and b.mass is None:
            lo, hi = model.mass
            b = replace(b, mass=math.exp(other.uniform(math.log(lo), math.log(hi))))
        out.append(b)
    return scene.with_boxes(out)
