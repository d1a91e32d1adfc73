"""What the camera cannot know, and pure functions that draw one plausible shelf from it.

A camera sees front faces. It does not see a box's depth or mass, the friction
of its cardboard, its own error on each face (about 1 cm), or how exactly the
robot's suction pull will go (lift or drag, speed, force limit). A prediction
is only as good as the worst plausible draw of all of these, so every sample
world is one such draw: `draw_world(scene, seed, k, model) -> (Scene, PhysicsConfig)`,
a pure function of its arguments (same seed, same world). The depth comes first:
`depth_range` bounds what a box hidden behind its front face can be, and
`sample_depths` is the method's original sampler (depth only).

The ranges are written up, with how they were chosen, in docs/physics.md
("What the camera cannot know").
"""
from __future__ import annotations

import math
import random
import zlib
from dataclasses import dataclass, replace

from shelfpick.perception.scene import BOX_TYPES, Box, Scene, quat_to_matrix
from shelfpick.planning.physics import PhysicsConfig

PULL_MODES = ("lift", "drag", "ride")


# --------------------------------------------------------------------------
# depth: the camera sees the front face, the box behind it is a guess
def depth_range(scene: Scene, box: Box, config: PhysicsConfig | None = None) -> tuple[float, float]:
    """(lowest, highest) depth a box with unknown depth may have.

    The highest keeps every back corner in front of the back wall and in front
    of any box whose front face lies behind this one's (a hidden box cannot
    pass through a visible one). The lowest is `min_sample_depth` (0.15 m, the
    shallowest of the method's box types is 0.17 m), never above the highest.
    """
    cfg = config or PhysicsConfig()
    r = quat_to_matrix(box.orientation)
    face = _face(box)
    face_max_y = max(c[1] for c in face)
    dy = r[1][1]  # how much of the box's depth axis points into the shelf
    if dy < 0.2:
        return (box.size[1], box.size[1])  # lying sideways: the depth is not along y; keep it
    hi = (scene.shelf.depth - face_max_y) / dy
    x0, x1 = min(c[0] for c in face), max(c[0] for c in face)
    z0, z1 = min(c[2] for c in face), max(c[2] for c in face)
    for other in scene.boxes:
        if other.id == box.id:
            continue
        cs = other.corners() if other.depth_known else _face(other)
        ox0, ox1 = min(c[0] for c in cs), max(c[0] for c in cs)
        oz0, oz1 = min(c[2] for c in cs), max(c[2] for c in cs)
        oy0 = min(c[1] for c in cs)
        # only a face really behind this one bounds it: a neighbour in the same column
        # overlaps by a few mm through tilt or noise, and bounding by it gave 1 cm deep boxes
        ov = _OCCLUSION_OVERLAP
        if ox0 < x1 - ov and x0 + ov < ox1 and oz0 < z1 - ov and z0 + ov < oz1 and oy0 > face_max_y - 0.005:
            bound = (oy0 - face_max_y) / dy
            if bound >= cfg.min_sample_depth:
                hi = min(hi, bound)
    hi = max(hi, 0.01)
    lo = min(cfg.min_sample_depth, hi)
    return (lo, hi)


_OCCLUSION_OVERLAP = 0.05  # m of face overlap in x and in z before a face counts as behind another


def _face(b: Box) -> list:
    r = quat_to_matrix(b.orientation)
    f = b.front_center
    hx, hz = b.size[0] / 2, b.size[2] / 2
    return [tuple(f[i] + sx * r[i][0] * hx + sz * r[i][2] * hz for i in range(3))
            for sx in (-1, 1) for sz in (-1, 1)]


def depth_ranges(scene: Scene, config: PhysicsConfig | None = None) -> dict[str, tuple[float, float]]:
    """`depth_range` of every box with an unknown depth (the same for every sample: compute once)."""
    return {b.id: depth_range(scene, b, config) for b in scene.boxes if not b.depth_known}


def sample_depths(scene: Scene, seed: int, sample: int, config: PhysicsConfig | None = None,
                  reach: float = 1.0, ranges: dict[str, tuple[float, float]] | None = None) -> Scene:
    """One depth sample of the scene: unknown depths drawn uniformly in `depth_range`.

    Ranges are computed on the scene as perceived (placeholder depths for the
    others are not used as obstacles: only front faces and known boxes are).
    `reach` < 1 shrinks each range towards its lowest depth (used to redraw a
    sample whose boxes, turned in the plane, swing into a neighbour).
    `ranges` (from `depth_ranges(scene, config)`) saves recomputing them per sample.
    """
    rng = random.Random(f"shelfpick-depth:{int(seed)}:{int(sample)}")
    out = []
    for b in scene.boxes:
        if b.depth_known:
            out.append(b)
            continue
        lo, hi = ranges[b.id] if ranges is not None else depth_range(scene, b, config)
        d = rng.uniform(lo, lo + (hi - lo) * reach)
        out.append(b.with_depth(d))
    return scene.with_boxes(out)


def _stable_seed(*parts: object) -> int:
    return zlib.crc32(":".join(str(p) for p in parts).encode())


def trial_seed(seed: int, sample: int, removed: frozenset[str], box: str) -> int:
    """The vibration seed of one pull: a pure function of what is pulled where."""
    return _stable_seed(seed, sample, ",".join(sorted(removed)), box)


# --------------------------------------------------------------------------
# everything else the camera cannot know


@dataclass(frozen=True)
class Uncertainty:
    """Ranges of the quantities a prediction draws per sample world.

    Every range is (low, high); a range with low == high pins the quantity.
    `depth_known` boxes keep their depth; boxes with a `mass` keep it.
    """

    mass: tuple[float, float] = (0.3, 5.0)          # kg per box, log-uniform (an empty carton to books)
    friction: tuple[float, float] = (0.6, 0.9)      # cardboard on cardboard/board, one per world
    face_error: float = 0.005                        # m, half-range of each face's centre error (x, z)
    face_size_error: float = 0.0                     # m, half-range of each face's width and height error
    face_depth_error: float = 0.0                    # m, half-range of each face's error along its normal
    pull_speed: tuple[float, float] = (0.2, 0.5)    # m/s
    pull_force: tuple[float, float] = (100.0, 200.0)  # N, the suction drive's force limit
    # how the arm pulls: "lift" (a few mm up, then straight out), "drag" (straight out on its
    # support, the arm holding the height), "ride" (on its support, height free: the method's
    # original drive, kept for comparisons); one mode per world, drawn evenly
    pull_modes: tuple[str, ...] = ("lift", "drag")
    # the stock's box types (w, d, h, m): a front face within `catalogue_tol` of a type's face is
    # that type in a share `catalogue_trust` of the worlds, its depth the type's third side
    # +- `catalogue_depth_error`; the other worlds (and faces no type explains) draw the depth
    # uniformly in `depth_range`. () turns the prior off.
    catalogue: tuple[tuple[float, float, float], ...] = tuple(BOX_TYPES.values())
    catalogue_tol: float = 0.025
    catalogue_trust: float = 1.0
    catalogue_depth_error: float = 0.01

    @classmethod
    def none(cls) -> "Uncertainty":
        """Only the depth is drawn (the method's original model): for comparisons and tests."""
        return cls(mass=(0.0, 0.0), friction=(0.0, 0.0), face_error=0.0, face_size_error=0.0,
                   face_depth_error=0.0, pull_speed=(0.0, 0.0),
                   pull_force=(0.0, 0.0), pull_modes=(), catalogue=())

    def without_face_error(self) -> "Uncertainty":
        """The same model for a shelf whose geometry is known (a scene file, the truth)."""
        return replace(self, face_error=0.0, face_size_error=0.0, face_depth_error=0.0)

    @property
    def draws_mass(self) -> bool:
        return self.mass[1] > 0

    @property
    def draws_physics(self) -> bool:
        """Whether a draw changes more than the geometry: masses, friction or the pull."""
        return (self.draws_mass or self.friction[1] > 0 or self.pull_speed[1] > 0 or self.pull_force[1] > 0
                or bool(self.pull_modes))

    def to_json(self) -> dict:
        return {"mass_kg": list(self.mass), "friction": list(self.friction), "face_error_m": self.face_error,
                "face_size_error_m": self.face_size_error, "face_depth_error_m": self.face_depth_error,
                "pull_speed_m_s": list(self.pull_speed), "pull_force_n": list(self.pull_force),
                "pull_modes": list(self.pull_modes), "catalogue": [list(t) for t in self.catalogue],
                "catalogue_tol_m": self.catalogue_tol, "catalogue_trust": self.catalogue_trust,
                "catalogue_depth_error_m": self.catalogue_depth_error}


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


def type_depths(box: Box, catalogue: tuple[tuple[float, float, float], ...], tol: float,
                highest: float) -> tuple[float, ...]:
    """The depths a box may have if it is one of the `catalogue` types: the third side of every
    type that has a face within `tol` of the box's front face (width x height) and that fits in
    front of `highest` (+ tol). Empty when no type explains the face."""
    w, h = box.size[0], box.size[2]
    out = set()
    for t in catalogue:
        for i in range(3):
            for j in range(3):
                if i == j:
                    continue
                d = t[3 - i - j]
                if abs(t[i] - w) <= tol and abs(t[j] - h) <= tol and d <= highest + tol:
                    out.add(round(float(d), 4))
    return tuple(sorted(out))


def _catalogue_depth(box: Box, model: Uncertainty, lo_hi: tuple[float, float],
                     rng: random.Random) -> float | None:
    """A depth for `box` from the stock's types, or None when this world does not take it as a type."""
    if not model.catalogue or rng.random() >= model.catalogue_trust:
        return None
    lo, hi = lo_hi
    depths = type_depths(box, model.catalogue, model.catalogue_tol, hi)
    if not depths:
        return None
    d = depths[rng.randrange(len(depths))]
    d += rng.uniform(-model.catalogue_depth_error, model.catalogue_depth_error)
    return min(max(d, 0.01), hi)


def depth_of(box: Box, depth: float) -> Box:
    """`box` with `depth`, its front face kept."""
    return box.with_depth(depth)


def _shifted(b: Box, dx: float, dy: float, dz: float) -> Box:
    """`b` moved by (dx, dy, dz) in its own frame (x along the face, y into the shelf, z up the face)."""
    r = quat_to_matrix(b.orientation)
    shift = tuple(r[i][0] * dx + r[i][1] * dy + r[i][2] * dz for i in range(3))
    return replace(b, position=tuple(b.position[i] + shift[i] for i in range(3)))


def _face_size_and_depth(b: Box, model: Uncertainty, rng: random.Random) -> Box:
    """`b` with its face's width and height off by up to `face_size_error` (the face's centre
    kept) and the face moved along its normal by up to `face_depth_error`."""
    if model.face_size_error > 0:
        dw = rng.uniform(-model.face_size_error, model.face_size_error)
        dh = rng.uniform(-model.face_size_error, model.face_size_error)
        w, d, h = b.size
        b = replace(b, size=(max(w + dw, 0.02), d, max(h + dh, 0.02)))
    if model.face_depth_error > 0:
        b = _shifted(b, 0.0, rng.uniform(-model.face_depth_error, model.face_depth_error), 0.0)
    return b


def draw_scene(scene: Scene, seed: int, k: int, model: Uncertainty,
               ranges: dict[str, tuple[float, float]], reach: float = 1.0) -> Scene:
    """The shelf of draw `k`: each unknown depth uniform in its range (shrunk by `reach`),
    each unknown mass log-uniform, each face moved by up to `face_error` in x and z, its width
    and height off by up to `face_size_error` and its place along its normal by `face_depth_error`.

    `ranges` are the depth ranges of the boxes with unknown depth (`depth_ranges`).
    A face that one of the stock's types explains takes that type's depth (`type_depths`;
    only at full reach: a redraw that reaches less deep is looking for another explanation).
    The depth draws use the same stream as the method's original sampler, so with
    `Uncertainty.none()` a draw is exactly the old depth sample.
    """
    depth_rng = random.Random(f"shelfpick-depth:{int(seed)}:{int(k)}")
    type_rng = _rng(seed, k, "types")
    other = _rng(seed, k, "boxes")
    faces = _rng(seed, k, "faces")   # its own stream: turning it on leaves every other draw as it was
    out = []
    for b in scene.boxes:
        if not b.depth_known:
            lo, hi = ranges[b.id]
            d = depth_rng.uniform(lo, lo + (hi - lo) * reach)
            typed = _catalogue_depth(b, model, (lo, hi), type_rng) if reach >= 1.0 else None
            b = depth_of(b, d if typed is None else typed)
        if model.face_error > 0:
            dx = other.uniform(-model.face_error, model.face_error)
            dz = other.uniform(-model.face_error, model.face_error)
            b = _shifted(b, dx, 0.0, dz)   # the face moves in its own plane
        b = _face_size_and_depth(b, model, faces)
        if model.draws_mass and b.mass is None:
            lo, hi = model.mass
            b = replace(b, mass=math.exp(other.uniform(math.log(lo), math.log(hi))))
        out.append(b)
    return scene.with_boxes(out)
