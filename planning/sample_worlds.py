"""The sample worlds of a prediction: one settled PyBullet world per draw of what the camera cannot know.

A draw that does not stand as observed (a box that moves or falls while it settles,
or at a small knock) contradicts the image: it is redrawn, and when no draw stands the
boxes that did not are reported (`scene_check`), never silently planned on.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, field
from typing import Mapping, Sequence

from shelfpick.perception.errors import SceneError
from shelfpick.perception.scene import Scene
from shelfpick.planning.bullet_clients import ClientPool
from shelfpick.planning.overlap_repair import OverlapError
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.sim import ShelfSim
from shelfpick.planning.step_result import StepResult
from shelfpick.planning.uncertainty import (
    Uncertainty,
    depth_ranges,
    draw_config,
    draw_scene,
    trial_seed,
)


@dataclass(frozen=True)
class Draw:
    """One sample world as built: the world, and what the draws before it contradicted."""

    sim: ShelfSim
    rejected: tuple[Mapping[str, str], ...] = ()   # per redrawn attempt: box -> what it did
    stands: bool = True                           # False: no attempt stood as observed
    off: Mapping[str, str] = field(default_factory=dict)  # what the returned world contradicts

    @property
    def repairs(self) -> tuple[str, ...]:
        return self.sim.repairs


def contradictions(sim: ShelfSim, config: PhysicsConfig, knock: bool = True) -> dict[str, str]:
    """Boxes of a freshly settled world (nothing run in it since it was built) that did not stand
    as they were given, with what they did.

    A box that drops straight down onto what is below it by up to `stand_drop` stood: the
    heights of the faces under it add up their measurement errors. Standing still is not
    enough: a box balanced on an edge stays put in a solver that nothing disturbs, so the
    settled world also takes a small knock
    (`ShelfSim.nudge`), and a box that then falls did not stand either (only a
    world that settled is knocked: the knock costs a settle).
    """
    out = {}
    for bid, (d, a) in sim.settle_moves.items():
        pos = sim.scene.box(bid).position
        side, dz = sim.settle_offsets[bid]
        if pos[2] < 0 or pos[1] < -config.off_shelf_front:
            out[bid] = f"falls off the shelf while settling (moved {d:.2f} m)"
        elif side > config.stand_tolerance or dz > config.stand_tolerance:
            out[bid] = f"moves {d:.3f} m while settling (more than {config.stand_tolerance:.2f} m)"
        elif -dz > config.stand_drop:
            out[bid] = (f"drops {-dz:.3f} m while settling (more than {config.stand_drop:.2f} m: "
                        f"nothing seen holds it where it is seen)")
        elif a > config.stand_rotation:
            out[bid] = f"turns {a:.0f} deg while settling (more than {config.stand_rotation:.0f} deg)"
    if out or knock is False:
        return out
    for bid, (d, a) in sim.nudge(config.stand_nudge, now=sim.start_state).items():
        if d > config.stand_tolerance or a > config.stand_rotation:
            out[bid] = f"falls over at a small knock (moved {d:.2f} m, turned {a:.0f} deg): it cannot stand as seen"
    return out


_ATTEMPTS = (1.0, 1.0, 1.0, 0.66, 0.33, 0.0)   # reach of each attempt's depth draw, then as perceived


def _world(scene: Scene, seed: int, k: int, model: Uncertainty, depths: dict[str, tuple[float, float]],
           reach: float, config: PhysicsConfig, clients: ClientPool | None) -> ShelfSim:
    """Draw `k` of the scene (geometry, then physics) built and settled, its repair warnings kept
    quiet (the scene check reports what matters); SceneError when it cannot be built."""
    sc = draw_scene(scene, seed, k, model, depths, reach)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ShelfSim(sc, draw_config(config, seed, k, model), local=config.prediction_local, clients=clients)


def build_sample(scene: Scene, seed: int, sample: int, config: PhysicsConfig,
                 ranges: dict[str, tuple[float, float]] | None = None,
                 model: Uncertainty | None = None, clients: ClientPool | None = None) -> Draw:
    """The settled world of draw `sample`; a draw that does not stand as observed is redrawn.

    A draw contradicts the image when a box moves more than `stand_tolerance` or
    turns more than `stand_rotation` while it settles, or when its overlaps cannot
    be repaired. Later attempts reach less deep (a box turned in the plane swings
    its back corners into its neighbours). When no attempt stands, the attempt
    that moved the fewest boxes comes back with ``stands=False``: the caller must
    say so, never plan on it as if it were the shelf. Every sample makes every
    attempt: a box that failed all of them in one sample may stand in another's, and
    the scene check counts samples (a shortcut that took an earlier sample's failures
    as given called 3 of the judge's 40 shelves not standing at exact faces, where
    their own draws called 1: docs/results/risk-gate.md, "Session 54").
    `clients`: where the worlds' Bullet clients come from (a fresh one each when None).
    """
    model = model if model is not None else Uncertainty()
    if scene.depth_known:
        return _draw_known(scene, seed, sample, config, model, clients)
    ranges = ranges if ranges is not None else depth_ranges(scene, config)
    as_seen = {b.id: (b.size[1], b.size[1]) for b in scene.boxes if not b.depth_known}
    return _draw_hidden(scene, seed, sample, config, model, ranges, as_seen, clients)


def _draw_known(scene: Scene, seed: int, sample: int, config: PhysicsConfig, model: Uncertainty,
                clients: ClientPool | None) -> Draw:
    """A known shelf is given as it stands: its geometry is not drawn, but what no scene file says
    still is (a box's mass when it has none, the friction, the pull); a draw under which the shelf
    seen standing never comes to rest contradicts the scene and is drawn again."""
    failed: list[dict[str, str]] = []
    for attempt in range(len(_ATTEMPTS) + 1):
        try:
            sim = _world(scene, seed, sample + 1000 * attempt, model.without_face_error(), {}, 1.0, config,
                         clients)
        except SceneError as exc:
            failed.append({"*": str(exc)})
            continue
        off = contradictions(sim, config)
        return Draw(sim, tuple(failed) + ((off,) if off else ()), not off, off)
    raise SceneError(f"no draw of sample {sample} can be built: {failed[-1]['*']}")


def _draw_hidden(scene: Scene, seed: int, sample: int, config: PhysicsConfig, model: Uncertainty,
                 ranges: dict[str, tuple[float, float]], as_seen: dict[str, tuple[float, float]],
                 clients: ClientPool | None) -> Draw:
    """Attempts of ever shallower depth draws (the last one the perceived placeholder depths) until
    one stands; else the one that moved the fewest boxes."""
    rejected: list[dict[str, str]] = []
    best: ShelfSim | None = None
    best_off: dict[str, str] = {}
    for attempt, reach in enumerate(_ATTEMPTS + (None,)):
        try:
            # the last resort keeps perception's placeholder depths, which perception made valid
            sim = _world(scene, seed, sample + 1000 * attempt, model, as_seen if reach is None else ranges,
                         reach or 0.0, config, clients)
        except SceneError as exc:  # overlaps past repair, or a world that never comes to rest
            rejected.append({"*": str(exc)})
            continue
        off = contradictions(sim, config)
        if not off:
            if best is not None:
                best.close()
            return Draw(sim, tuple(rejected), True, off)
        rejected.append(off)
        best, best_off = _fewer_moved(best, best_off, sim, off)
    if best is None:
        return _draw_as_perceived(scene, seed, sample, config, model, as_seen, clients, tuple(rejected))
    return Draw(best, tuple(rejected), False, best_off)


def _fewer_moved(best: ShelfSim | None, best_off: dict[str, str], sim: ShelfSim,
                 off: dict[str, str]) -> tuple[ShelfSim, dict[str, str]]:
    """Of two worlds that do not stand, the one that moved fewer boxes (the earlier on a tie);
    the other is closed (each holds a Bullet client)."""
    if best is None or len(off) < len(best_off):
        if best is not None:
            best.close()
        return sim, off
    sim.close()
    return best, best_off


def _draw_as_perceived(scene: Scene, seed: int, sample: int, config: PhysicsConfig, model: Uncertainty,
                       as_seen: dict[str, tuple[float, float]], clients: ClientPool | None,
                       rejected: tuple[Mapping[str, str], ...]) -> Draw:
    """No draw could be built at all: a face error drawn on top of two faces measured close together
    can push them past repair in every attempt. The shelf exactly as perceived (placeholder depths,
    no drawn face error) is what perception made valid; if it cannot be built either, the image
    itself is contradictory and the plan is refused."""
    try:
        best = _world(scene, seed, sample + 1000 * len(_ATTEMPTS), model.without_face_error(), as_seen, 0.0,
                      config, clients)
    except SceneError as exc:
        # one line that says whose fault it is: perception's faces, not the draws (issue 31)
        raise OverlapError(f"no draw of sample {sample} can be built: {exc}; not even as perceived "
                           f"(no drawn error): the perceived faces cannot all be right",
                           getattr(exc, "boxes", ()), str(exc)) from None
    best_off = contradictions(best, config)
    return Draw(best, rejected, not best_off, best_off)


@dataclass(frozen=True)
class DrawSummary:
    """A `Draw` as another process sees it: what it found, not the world (which stays put)."""

    scene: Scene
    rejected: tuple
    stands: bool
    off: Mapping[str, str]
    repairs: tuple[str, ...]

    @classmethod
    def of(cls, draw: Draw) -> "DrawSummary":
        return cls(draw.sim.scene, draw.rejected, draw.stands, draw.off, draw.repairs)


def not_standing(draw: Draw | DrawSummary) -> frozenset[str]:
    """The boxes that contradict the image in the world this draw settled on."""
    return frozenset() if draw.stands else frozenset(b for b in draw.off if b != "*")


def scene_check(draws: Sequence[Draw | DrawSummary]) -> dict:
    """Whether the observed shelf stands as seen, from the sample worlds' draws.

    A box is a problem when no attempt of a sample made it stand, in at least
    half of the samples: then no plausible draw of what the camera cannot know
    explains the image. (A box that fails in one sample of ten is explained by
    the others; that sample's world is the attempt that contradicts least.)
    """
    fails: dict[str, list[str]] = {}
    redrawn = 0
    for d in draws:
        redrawn += len(d.rejected)
        for bid in not_standing(d):
            fails.setdefault(bid, []).append(d.off[bid])
    problems = {b: whats[0] for b, whats in fails.items() if 2 * len(whats) >= len(draws)}
    return {"stands_as_seen": not problems, "redrawn": redrawn,
            "samples_not_standing": sum(1 for d in draws if not d.stands),
            "problems": [{"box": b, "what": w} for b, w in sorted(problems.items())],
            # what the first sample world had to repair (overlaps pushed apart, boxes settled)
            "repairs": list(draws[0].repairs) if draws else []}


class SampleWorlds:
    """Some of the sample worlds (all of them, or one worker's share) and their cached states.

    Each world is built and settled once; the state after taking a set of boxes away is
    cached with saveState, so every trial starts from a restoreState and costs one pull.
    """

    def __init__(self, scene: Scene, seed: int, config: PhysicsConfig, indices: Sequence[int],
                 model: Uncertainty | None = None, clients: ClientPool | None = None):
        self.seed = seed
        self.scene, self.config, self.model, self.clients = scene, config, model, clients
        self.local = config.prediction_local
        self.order = {b: i for i, b in enumerate(scene.ids)}
        self.sims: dict[int, ShelfSim] = {}
        self.draws: dict[int, Draw] = {}
        self.states: dict[int, dict] = {}
        self._ranges = depth_ranges(scene, config) if not scene.depth_known else None
        try:
            self.add(indices)
        except BaseException:
            self.close()
            raise
        self.new_states = 0

    def add(self, indices: Sequence[int]) -> dict[int, Draw]:
        """Build the worlds of `indices` as well; a world is the same whether it was built here or
        with the first ones."""
        out = {}
        for i in indices:
            if i in self.sims:
                raise ValueError(f"sample {i} is already built")
            d = build_sample(self.scene, self.seed, i, self.config, self._ranges, self.model, self.clients)
            self.draws[i] = out[i] = d
            self.sims[i] = d.sim
            self.states[i] = {frozenset(): d.sim.start_state}   # (knocked, then put back as built)
        return out

    def state(self, i: int, removed: frozenset[str]):
        st = self.states[i]
        snap = st.get(removed)
        if snap is None:
            sim = self.sims[i]
            sim.restore(st[frozenset()])
            sim.delete_many(sorted(removed, key=self.order.__getitem__), local=self.local)
            snap = sim.snapshot()
            st[removed] = snap
            self.new_states += 1
        return snap

    def pull(self, i: int, removed: frozenset[str], box: str) -> StepResult:
        sim = self.sims[i]
        sim.restore(self.state(i, removed))
        return sim.remove(box, seed=trial_seed(self.seed, i, removed, box), stop_on_collapse=True,
                          local=self.local)

    def preview(self, sequence: Sequence[str], i: int) -> list[StepResult]:
        sim = self.sims[i]
        removed: frozenset[str] = frozenset()
        out = []
        sim.restore(self.states[i][frozenset()])
        try:
            for box in sequence:
                out.append(sim.remove(box, seed=trial_seed(self.seed, i, removed, box), record=True))
                removed = removed | {box}
        finally:
            sim.restore(self.states[i][frozenset()])
        return out

    def close(self) -> None:
        for sim in self.sims.values():
            sim.close()
        self.sims = {}
