"""The shelf as a PyBullet world: build, repair, settle, pull a box out, judge.

One `ShelfSim` owns one `BulletClient` (DIRECT unless `gui=True`), never
pybullet's global state. The body set is fixed at construction: a removed box
is *parked* far away on a floor of its own instead of being deleted, so that
`saveState`/`restoreState` (which need the same bodies) keep working and a
trial can be rolled back in ~0.1 ms instead of rebuilding the world.

A removal is judged against the settled poses at the start of the step, so
Bullet's slow creep and jitter of resting stacks never reads as a collapse.
"""
from __future__ import annotations

import math
import warnings
import weakref
from contextlib import contextmanager
from dataclasses import replace
from typing import Iterator

from shelfpick.perception.errors import SceneError
from shelfpick.perception.scene import Box, Quat, Scene, Vec3, wxyz_to_xyzw, xyzw_to_wxyz
from shelfpick.planning.bullet_clients import Client, ClientPool, connect, disconnect_quietly
from shelfpick.planning.geometry3 import dist as _dist
from shelfpick.planning.geometry3 import norm as _norm
from shelfpick.planning.geometry3 import rot_angle_deg as _rot_angle_deg
from shelfpick.planning.locality import neighbourhood as _neighbourhood
from shelfpick.planning.overlap_repair import clear_perches, repair_overlaps
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.pull import pull
from shelfpick.planning.step_result import StepResult
from shelfpick.planning.unexplained import obstacles

_PARK_X0 = 50.0      # parked boxes are put far from the shelf, out of the broadphase
_PARK_DX = 3.0
_PARK_Z = -50.0
_GRIPPER_PARK = (-50.0, 0.0, -50.0)


class ShelfSim:
    """One scene in one PyBullet world, settled, ready for removal trials."""

    def __init__(self, scene: Scene, config: PhysicsConfig | None = None, *, gui: bool = False,
                 local: bool = False, clients: ClientPool | None = None):
        """`local=True` also builds the static stand-ins that local trials need (see `remove`).
        `clients`: a pool to take the Bullet client from and give it back to on `close`
        (a client of its own, disconnected on `close`, when None or with `gui`)."""
        self.config = cfg = config or PhysicsConfig()
        self._gui = gui
        self._clients = clients if not gui else None
        self._p: Client | None = self._clients.acquire() if self._clients else connect(gui)
        # a simulation nobody closed still disconnects its own client when it is collected
        self._finalizer = weakref.finalize(self, disconnect_quietly, self._p) if self._clients is None else None
        p = self._p
        p.setGravity(0, 0, -cfg.gravity)
        p.setTimeStep(cfg.time_step)
        p.setPhysicsEngineParameter(numSolverIterations=int(cfg.solver_iterations),
                                    deterministicOverlappingPairs=1)
        self._gui = gui
        self._input = scene
        self._ids: tuple[str, ...] = scene.ids
        self._boxes: dict[str, Box] = {b.id: b for b in scene.boxes}
        self._static: dict[int, str] = {}
        self._build_shelf(scene)
        for name, half, centre in obstacles(scene):    # unexplained matter: static, where perception saw it
            self._static_box(name, half, centre)
        self._body: dict[str, int] = {}
        self._half: dict[str, tuple[float, float, float]] = {}
        self._shape: dict[str, int] = {}
        self._twin: dict[str, int] = {}      # box -> its static stand-in (local trials only)
        self._frozen: dict[str, tuple] = {}  # boxes standing in as static copies right now
        for b in scene.boxes:
            self._body[b.id] = self._add_box(b)
        self._box_of = {v: k for k, v in self._body.items()}
        self._gripper = self._add_gripper()
        self._parked: set[str] = set()
        self.sim_time = 0.0

        after = self._repair_and_settle()
        if local:
            for i, bid in enumerate(self._ids):
                self._twin[bid] = self._add_twin(bid, i)
        self._twin_of = {v: k for k, v in self._twin.items()}
        snap = self.snapshot()   # start every world from a canonical state (see `restore`)
        self.restore(snap)
        # the world as built, kept (a saveState costs 2-3 ms): a fresh world's knock and its
        # trials' first state restore it instead of saving the same state again
        self.start_state: tuple[int, frozenset[str]] = snap
        self.scene: Scene = scene.with_boxes(
            replace(b, position=after[b.id][0], orientation=after[b.id][1]) for b in scene.boxes)

    def _repair_and_settle(self) -> dict[str, tuple[Vec3, Quat]]:
        """Push overlaps apart, settle, and say what moved (`repairs`, `settle_moves`); the poses at rest."""
        cfg = self.config
        try:
            repairs = repair_overlaps(self._p, self._ids, self._body, self._static, cfg)
            perches = clear_perches(self._p, self._ids, self._body, cfg)
            if perches:   # moving a box off an edge may push it into a side neighbour
                repairs += perches + repair_overlaps(self._p, self._ids, self._body, self._static, cfg)
        except SceneError:
            self.close()
            raise
        before = self.raw_poses(self._ids)
        if not self._settle(cfg.initial_settle_time):
            moving = self._moving()
            self.close()
            raise SceneError(f"scene does not come to rest within {cfg.initial_settle_time:g} s: "
                             f"box(es) {', '.join(moving)} still moving")
        after = self.raw_poses(self._ids)
        # how far each box moved and turned while settling, from where it was put (after the
        # overlap repair): a box that moves far did not stand as it was given (predict.py)
        self.settle_moves: dict[str, tuple[float, float]] = {
            bid: (_dist(before[bid][0], after[bid][0]), _rot_angle_deg(before[bid][1], after[bid][1]))
            for bid in self._ids}
        # the same move split: (sideways, vertical with sign): a box may drop onto its support
        self.settle_offsets: dict[str, tuple[float, float]] = {
            bid: (math.hypot(after[bid][0][0] - before[bid][0][0], after[bid][0][1] - before[bid][0][1]),
                  after[bid][0][2] - before[bid][0][2]) for bid in self._ids}
        for bid in self._ids:
            d, dz = self.settle_moves[bid][0], self.settle_offsets[bid][1]
            if d > cfg.settle_report:
                what = "dropped onto its support" if dz < -0.7 * d else "shifted while settling"
                repairs.append(f"box {bid!r} {what}: moved {d:.3f} m")
        for msg in repairs:
            warnings.warn(f"scene repaired: {msg}", stacklevel=3)
        self.repairs: tuple[str, ...] = tuple(repairs)
        return after

    # ------------------------------------------------------------------ build
    def _static_box(self, name: str, half: Vec3, pos: Vec3) -> int:
        p = self._p
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half))
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=list(half), rgbaColor=[0.6, 0.6, 0.65, 1]) \
            if self._gui else -1
        body = p.createMultiBody(0.0, col, vis, list(pos))
        p.changeDynamics(body, -1, lateralFriction=self.config.lateral_friction,
                         spinningFriction=self.config.spinning_friction, restitution=0.0)
        self._static[body] = name
        return body

    def _build_shelf(self, scene: Scene) -> None:
        s, t = scene.shelf, self.config.wall_thickness
        w2 = s.width / 2
        self._static_box("floor", (w2 + t, (s.depth + t) / 2, t / 2), (0.0, (s.depth + t) / 2, -t / 2))
        self._static_box("back wall", (w2 + t, t / 2, s.height / 2 + t), (0.0, s.depth + t / 2, s.height / 2))
        for side, x in (("left wall", -w2 - t / 2), ("right wall", w2 + t / 2)):
            self._static_box(side, (t / 2, (s.depth + t) / 2, s.height / 2 + t),
                             (x, (s.depth + t) / 2, s.height / 2))
        if self.config.shelf_top:
            self._static_box("top", (w2 + t, (s.depth + t) / 2, t / 2),
                             (0.0, (s.depth + t) / 2, s.height + t / 2))
        g = self.config.ground_drop
        self._static_box("ground", (10.0, 10.0, 0.05), (0.0, 0.0, -g - 0.05))

    def _add_box(self, b: Box) -> int:
        p, cfg = self._p, self.config
        half = tuple(x / 2 for x in b.size)
        self._half[b.id] = half  # type: ignore[assignment]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=list(half))
        self._shape[b.id] = col
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=list(half), rgbaColor=[0.76, 0.6, 0.42, 1]) \
            if self._gui else -1
        mass = b.mass if b.mass is not None else cfg.density * b.size[0] * b.size[1] * b.size[2]
        body = p.createMultiBody(mass, col, vis, list(b.position), list(wxyz_to_xyzw(b.orientation)))
        # no sleeping: a body's sleep timer is not part of saveState, so it would make a
        # restored trial depend on what ran before it (same seed must give the same result)
        p.changeDynamics(body, -1, lateralFriction=cfg.lateral_friction,
                         spinningFriction=cfg.spinning_friction, restitution=0.0,
                         activationState=p.ACTIVATION_STATE_DISABLE_SLEEPING)
        return body

    def _add_twin(self, bid: str, i: int) -> int:
        """A static copy of a box, out of the broadphase until a local trial freezes the box."""
        p, cfg = self._p, self.config
        body = p.createMultiBody(0.0, self._shape[bid], -1, [_PARK_X0 + _PARK_DX * i, 10.0, _PARK_Z])
        p.changeDynamics(body, -1, lateralFriction=cfg.lateral_friction,
                         spinningFriction=cfg.spinning_friction, restitution=0.0)
        p.setCollisionFilterGroupMask(body, -1, 0, 0)
        return body

    def _add_gripper(self) -> int:
        p = self._p
        half = [x / 2 for x in self.config.gripper_size]
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=[0.2, 0.3, 0.8, 1]) \
            if self._gui else -1
        return p.createMultiBody(0.0, col, vis, list(_GRIPPER_PARK))

    # ---------------------------------------------------------------- queries
    def raw_poses(self, ids) -> dict[str, tuple[Vec3, Quat]]:
        p = self._p
        out = {}
        for bid in ids:
            pos, orn = p.getBasePositionAndOrientation(self._body[bid])
            out[bid] = (tuple(pos), xyzw_to_wxyz(orn))
        return out

    def present(self) -> tuple[str, ...]:
        """Boxes still on the shelf (not removed, not fallen to the ground)."""
        p = self._p
        out = []
        for bid in self._ids:
            if bid in self._parked:
                continue
            pos, _ = p.getBasePositionAndOrientation(self._body[bid])
            if pos[2] > -self.config.fallen_below:
                out.append(bid)
        return tuple(out)

    def poses(self) -> dict[str, tuple[Vec3, Quat]]:
        return self.raw_poses(self.present())

    def active(self) -> list[str]:
        return [b for b in self._ids if b not in self._parked]

    def _moving(self, first: bool = False) -> list[str]:
        """The boxes on the shelf moving faster than rest (`first`: only the first one found; a
        settle only needs to know whether any does, and most of its steps have one early)."""
        cfg, velocity, body, frozen = self.config, self._p.getBaseVelocity, self._body, self._frozen
        rest_v, rest_w = cfg.rest_velocity, cfg.rest_angular_velocity
        out = []
        for bid in self._ids:
            if bid in self._parked or bid in frozen:
                continue
            lin, ang = velocity(body[bid])
            if _norm(lin) > rest_v or _norm(ang) > rest_w:
                out.append(bid)
                if first:
                    break
        return out

    # --------------------------------------------------------------- stepping
    def step(self) -> None:
        self._p.stepSimulation()
        self.sim_time += self.config.time_step

    def _settle(self, max_time: float) -> bool:
        """Step until every box on the shelf rests for `rest_window`; False if it never does."""
        cfg = self.config
        need = max(1, int(round(cfg.rest_window / cfg.time_step)))
        calm = 0
        for _ in range(int(math.ceil(max_time / cfg.time_step))):
            self.step()
            calm = calm + 1 if not self._moving(first=True) else 0
            if calm >= need:
                return True
        return False

    def nudge(self, spin: float, now: tuple[int, frozenset[str]] | None = None) -> dict[str, tuple[float, float]]:
        """How far (m, deg) each box ends up after a small knock, the world put back after.

        Every box on the shelf is set turning at `spin` rad/s about a horizontal axis
        (alternating x and y from box to box), then the world settles. A box at rest in
        a stable pose rocks back; one balanced on an edge (an unstable equilibrium the
        solver would otherwise keep forever) falls over. `now`: a snapshot of the world as
        it is (`start_state` of a world nothing ran in yet), put back instead of a new one.
        """
        p = self._p
        ids = self.present()
        before = self.raw_poses(ids)
        snap = now if now is not None else self.snapshot()
        t = self.sim_time
        try:
            for i, bid in enumerate(ids):
                axis = (spin, 0.0, 0.0) if i % 2 else (0.0, spin, 0.0)
                p.resetBaseVelocity(self._body[bid], [0.0, 0.0, 0.0], list(axis))
            self._settle(self.config.settle_time)
            after = self.raw_poses(ids)
        finally:
            self.restore(snap)
            if now is None:
                self.forget(snap)
            self.sim_time = t
        return {b: (_dist(before[b][0], after[b][0]), _rot_angle_deg(before[b][1], after[b][1])) for b in ids}

    def idle(self, seconds: float) -> dict[str, float]:
        """Let the world run untouched; how far (m) each box on the shelf moved.

        A settled shelf barely creeps. A stack that is still sliding or tipping
        slowly (under the rest velocity, so settling called it calm) moves
        centimetres, and every later step would misreport that as a collapse.
        """
        ids = self.present()
        before = self.raw_poses(ids)
        for _ in range(int(math.ceil(seconds / self.config.time_step))):
            self.step()
        after = self.raw_poses(ids)
        return {b: math.dist(before[b][0], after[b][0]) for b in ids}

    def park(self, bid: str) -> None:
        p = self._p
        i = self._ids.index(bid)
        h = self._boxes[bid].size[2] / 2
        body = self._body[bid]
        p.resetBasePositionAndOrientation(body, [_PARK_X0 + _PARK_DX * i, 0.0, _PARK_Z + h + 1e-3],
                                          [0, 0, 0, 1])
        p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0])
        # out of the broadphase: a parked box costs the solver nothing (it just falls freely,
        # far from everything, until a restore puts it back)
        p.setCollisionFilterGroupMask(body, -1, 0, 0)
        self._parked.add(bid)

    def free_lift(self, box_id: str) -> float:
        """How far the gripper may lift `box_id`: `pull_lift`, capped by the free space above it.

        Anything whose bounding box overlaps this box's footprint and starts above its
        top (another box, the shelf's top) bounds the lift; 2 mm are kept free.
        """
        p, cfg = self._p, self.config
        lo, hi = p.getAABB(self._body[box_id])
        gap = cfg.pull_lift + cfg.lift_clearance
        shrink = cfg.lift_footprint_shrink
        others = [self._body[b] for b in self.active() if b != box_id]
        others += [b for b, name in self._static.items() if name == "top"]
        for ob in others:
            olo, ohi = p.getAABB(ob)
            if (olo[0] < hi[0] - shrink and lo[0] + shrink < ohi[0] and olo[1] < hi[1] - shrink
                    and lo[1] + shrink < ohi[1] and ohi[2] > hi[2]):
                gap = min(gap, olo[2] - hi[2])
        return max(0.0, min(cfg.pull_lift, gap - cfg.lift_clearance))

    # --------------------------------------------------------------- locality
    def neighbourhood(self, seeds, *, corridor: bool = False) -> set[str]:
        """The boxes a change at `seeds` can move before the step is decided
        (`planning.locality.neighbourhood` over the boxes on the shelf now)."""
        p, cfg = self._p, self.config
        box = {b: p.getAABB(self._body[b]) for b in self.active()}
        return _neighbourhood(box, seeds, margin=cfg.local_margin, overlap=cfg.support_overlap,
                              tilt=cfg.support_tilt, corridor=corridor)

    def _freeze(self, keep) -> None:
        """Every box on the shelf outside `keep` stands in as a static copy of itself.

        Its dynamic body leaves the broadphase (it falls freely, touching nothing,
        and costs the solver nothing); `_thaw` puts it back as it was (the position
        bit for bit, the quaternion to its last bit: Bullet round-trips it).
        """
        p = self._p
        for bid in self.active():
            if bid in keep or bid in self._frozen:
                continue
            body, twin = self._body[bid], self._twin[bid]
            pos, orn = p.getBasePositionAndOrientation(body)
            lin, ang = p.getBaseVelocity(body)
            self._frozen[bid] = (pos, orn, lin, ang)
            p.resetBasePositionAndOrientation(twin, pos, orn)
            p.setCollisionFilterGroupMask(twin, -1, 2, -1 ^ 2)   # Bullet's default for static bodies
            p.setCollisionFilterGroupMask(body, -1, 0, 0)

    def _thaw(self) -> None:
        p = self._p
        for bid, (pos, orn, lin, ang) in self._frozen.items():
            body = self._body[bid]
            p.resetBasePositionAndOrientation(body, pos, orn)
            p.resetBaseVelocity(body, lin, ang)
            p.setCollisionFilterGroupMask(body, -1, 1, -1)
            p.setCollisionFilterGroupMask(self._twin[bid], -1, 0, 0)
        self._frozen.clear()

    def delete(self, box_id: str) -> None:
        """Take a box away without a pull (it vanishes), then let the rest settle."""
        self._require(box_id)
        self.park(box_id)
        self._settle(self.config.settle_time)

    def delete_many(self, box_ids, *, local: bool = False) -> None:
        """Take several boxes away at once, then settle once.

        `local=True` (a world built with `local=True`) settles only the boxes
        around the deleted ones (`neighbourhood`); the others stay where they were.
        """
        box_ids = list(box_ids)
        for b in box_ids:
            self._require(b)
        keep = self.neighbourhood(box_ids) if local and self._twin else None
        for b in box_ids:
            if b not in self._parked:
                self.park(b)
        if keep is None:
            self._settle(self.config.settle_time)
            return
        self._freeze(keep)
        try:
            self._settle(self.config.settle_time)
        finally:
            self._thaw()

    def _require(self, box_id: str) -> None:
        if box_id not in self._body:
            raise SceneError(f"unknown box id {box_id!r}; the scene has {', '.join(self._ids)}")

    # ------------------------------------------------------------- save/load
    def snapshot(self) -> tuple[int, frozenset[str]]:
        """An in-memory world state to `restore` later (same bodies, bit-exact)."""
        return (self._p.saveState(), frozenset(self._parked))

    def restore(self, snap: tuple[int, frozenset[str]]) -> None:
        """Back to a snapshot, bit-exact whatever ran in between.

        restoreState puts back poses and velocities but keeps contact manifolds
        of pairs that touch *now* (say, boxes still falling when a trial stopped at
        its first collapse); their warm-start impulses would leak into the next
        trial. Filtering every box out of the broadphase for one collision pass
        drops all manifolds, so a restored world depends on the snapshot only.
        """
        p = self._p
        p.restoreState(snap[0])
        for bid in self._frozen:   # a local trial that did not finish
            p.setCollisionFilterGroupMask(self._twin[bid], -1, 0, 0)
        self._frozen.clear()
        self._parked = set(snap[1])
        self.park_gripper()
        bodies = list(self._body.values()) + [self._gripper]
        for b in bodies:
            p.setCollisionFilterGroupMask(b, -1, 0, 0)
        p.performCollisionDetection()
        for bid, b in self._body.items():
            if bid not in self._parked:
                p.setCollisionFilterGroupMask(b, -1, 1, -1)  # Bullet's default for dynamic bodies
        p.setCollisionFilterGroupMask(self._gripper, -1, 2, -1 ^ 2)  # ... and for static ones

    def forget(self, snap: tuple[int, frozenset[str]]) -> None:
        self._p.removeState(snap[0])

    @contextmanager
    def rollback(self) -> Iterator["ShelfSim"]:
        """Run a trial and put the world back exactly as it was."""
        snap = self.snapshot()
        t = self.sim_time
        try:
            yield self
        finally:
            self.restore(snap)
            self.forget(snap)
            self.sim_time = t

    # ----------------------------------------------------------------- remove
    def remove(self, box_id: str, seed: int = 0, record: bool = False, *,
               stop_on_collapse: bool = False, local: bool = False) -> StepResult:
        """Pull `box_id` out with the suction gripper and judge what the rest did.

        `stop_on_collapse` ends the trial as soon as a collapse is certain (the
        planners only need the verdict and the first collapsing box).
        `local=True` (a world built with `local=True`, not recording) simulates only
        the box's `neighbourhood`; the other boxes stand in as static copies during
        the pull and are where they were afterwards (docs/speed.md).
        """
        self._require(box_id)
        if box_id in self._parked or box_id not in self.present():
            return StepResult(box_id, False, note="not on the shelf")
        if not (local and self._twin) or record:
            return self._pull(box_id, seed, record, stop_on_collapse)
        self._freeze(self.neighbourhood([box_id], corridor=True))
        try:
            return self._pull(box_id, seed, record, stop_on_collapse)
        finally:
            self._thaw()

    def _pull(self, box_id: str, seed: int, record: bool, stop_on_collapse: bool) -> StepResult:
        return pull(self, box_id, seed, record, stop_on_collapse)

    # ------------------------------------------------------- for a pull trial
    @property
    def client(self) -> Client:
        assert self._p is not None, "the simulation is closed"
        return self._p

    @property
    def ids(self) -> tuple[str, ...]:
        return self._ids

    @property
    def gripper_body(self) -> int:
        return self._gripper

    def body(self, box_id: str) -> int:
        return self._body[box_id]

    def half_extents(self, box_id: str) -> tuple[float, float, float]:
        return self._half[box_id]

    def frozen_twins(self) -> dict[str, int]:
        """The boxes standing in as static copies right now, and their copies' bodies."""
        return {b: self._twin[b] for b in self._frozen}

    def park_gripper(self) -> None:
        self._p.resetBasePositionAndOrientation(self._gripper, list(_GRIPPER_PARK), [0, 0, 0, 1])

    def close(self) -> None:
        """Give the client back to its pool (or disconnect it); the world is gone."""
        client, self._p = self._p, None
        if client is None:
            return
        if self._finalizer is not None:
            self._finalizer.detach()
        if self._clients is not None:
            self._clients.release(client)
        else:
            disconnect_quietly(client)

    def __enter__(self) -> "ShelfSim":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
