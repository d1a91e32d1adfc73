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

import functools
import math
import warnings
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from typing import Any, Iterator, Mapping

from perception.errors import SceneError
from perception.scene import Box, Quat, Scene, Vec3, quat_to_matrix, wxyz_to_xyzw, xyzw_to_wxyz
from planning.physics import PhysicsConfig

Frame = tuple[float, dict[str, tuple[Vec3, Quat]]]

_PARK_X0 = 50.0      # parked boxes are put far from the shelf, out of the broadphase
_PARK_DX = 3.0
_PARK_Z = -50.0
_GRIPPER_PARK = (-50.0, 0.0, -50.0)


@dataclass(frozen=True)
class StepResult:
    """What happened to the shelf when `box` was pulled out.

    `moved` are the other boxes that started moving (past the onset threshold),
    ordered by when they started; `collapsed` the subset past the collapse
    thresholds, in the same order (the first one drives backtracking);
    `collided` the neighbours the box or the gripper touched that then moved.
    """

    box: str
    extracted: bool
    collapsed: tuple[str, ...] = ()
    collided: tuple[str, ...] = ()
    displacement: Mapping[str, float] = field(default_factory=dict)
    rotation: Mapping[str, float] = field(default_factory=dict)
    moved: tuple[str, ...] = ()
    frames: tuple[Frame, ...] = ()
    sim_time: float = 0.0
    note: str = ""

    @property
    def ok(self) -> bool:
        """The box came out and nothing else collapsed."""
        return self.extracted and not self.collapsed

    @property
    def collision(self) -> bool:
        return bool(self.collided)

    def to_json(self, frames: bool = False) -> dict:
        doc: dict[str, Any] = {
            "box": self.box, "extracted": self.extracted, "ok": self.ok,
            "collapse": bool(self.collapsed), "collision": bool(self.collided),
            "collapsed": list(self.collapsed), "collided": list(self.collided),
            "moved": {b: round(self.displacement.get(b, 0.0), 4) for b in self.moved},
            "displacement": {k: round(v, 4) for k, v in self.displacement.items()},
            "rotation_deg": {k: round(v, 2) for k, v in self.rotation.items()},
            "sim_time": round(self.sim_time, 4),
        }
        if self.note:
            doc["note"] = self.note
        if frames and self.frames:
            doc["frames"] = [[t, {k: [list(p), list(q)] for k, (p, q) in poses.items()}]
                             for t, poses in self.frames]
        return doc


# --------------------------------------------------------------------------
# small vector helpers (plain floats: faster than numpy for 3-vectors)
def _rot_angle_deg(q0: tuple, q1: tuple) -> float:
    """Angle between two unit quaternions (any order convention, same for both)."""
    d = abs(q0[0] * q1[0] + q0[1] * q1[1] + q0[2] * q1[2] + q0[3] * q1[3])
    return math.degrees(2.0 * math.acos(min(1.0, d)))


def _dist(a: tuple, b: tuple) -> float:
    return math.sqrt((a[0] - b[0]) ** 2 + (a[1] - b[1]) ** 2 + (a[2] - b[2]) ** 2)


def _norm(v: tuple) -> float:
    return math.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2])


def _matvec(r: list[list[float]], v: tuple) -> tuple[float, float, float]:
    return (r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2])


def _connect(gui: bool):
    """A BulletClient whose C-level banner ("argv[0]=", build time) stays off stdout/stderr.

    `shelfpick simulate` prints JSON on stdout; pybullet's printf would corrupt it.
    """
    import os
    import sys

    sys.stdout.flush()
    sys.stderr.flush()
    saved = (os.dup(1), os.dup(2))
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.dup2(null, 2)   # the "pybullet build time" line goes to stderr on first import
    try:
        import pybullet
        from pybullet_utils.bullet_client import BulletClient

        client = BulletClient(connection_mode=pybullet.GUI if gui else pybullet.DIRECT)
    finally:
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        os.close(saved[0])
        os.close(saved[1])
        os.close(null)
    # BulletClient resolves every call through __getattr__ (a new partial each time);
    # binding the hot ones once saves ~20% of a trial's Python time.
    for name in _HOT_CALLS:
        setattr(client, name, functools.partial(getattr(pybullet, name), physicsClientId=client._client))
    return client


# Connecting a DIRECT client costs ~25 ms of CPU (it allocates a whole physics server),
# resetSimulation on one that is no longer used ~1.5 ms. A closed ShelfSim therefore hands
# its client back here and the next ShelfSim of this process reuses it: each client still
# belongs to one simulation object at a time. resetSimulation drops every body, constraint
# and saved state; the world parameters are set again by every ShelfSim.
_IDLE: list = []
_IDLE_PID: list[int] = [0]
_IDLE_MAX = 64


def _acquire(gui: bool):
    import os

    if _IDLE_PID[0] != os.getpid():  # a forked child must not share its parent's clients
        _IDLE.clear()
        _IDLE_PID[0] = os.getpid()
    if not gui and _IDLE:
        return _IDLE.pop()
    return _connect(gui)


def _release(client, gui: bool) -> None:
    import os

    if gui or len(_IDLE) >= _IDLE_MAX or _IDLE_PID[0] != os.getpid():
        client.disconnect()
        return
    client.resetSimulation()
    _IDLE.append(client)


_HOT_CALLS = ("getBasePositionAndOrientation", "getBaseVelocity", "stepSimulation", "getContactPoints",
              "changeConstraint", "resetBasePositionAndOrientation", "resetBaseVelocity",
              "applyExternalForce", "setCollisionFilterGroupMask", "performCollisionDetection")


class ShelfSim:
    """One scene in one PyBullet world, settled, ready for removal trials."""

    def __init__(self, scene: Scene, config: PhysicsConfig | None = None, *, gui: bool = False,
                 local: bool = False):
        """`local=True` also builds the static stand-ins that local trials need (see `remove`)."""
        self.config = cfg = config or PhysicsConfig()
        self._gui = gui
        self._p = _acquire(gui)
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

        repairs = list(self._repair_overlaps())
        before = self._raw_poses(self._ids)
        if not self._settle(cfg.initial_settle_time):
            moving = self._moving()
            self.close()
            raise SceneError(f"scene does not come to rest within {cfg.initial_settle_time:g} s: "
                             f"box(es) {', '.join(moving)} still moving")
        after = self._raw_poses(self._ids)
        # how far each box moved and turned while settling, from where it was put (after the
        # overlap repair): a box that moves far did not stand as it was given (predict.py)
        self.settle_moves: dict[str, tuple[float, float]] = {
            bid: (_dist(before[bid][0], after[bid][0]), _rot_angle_deg(before[bid][1], after[bid][1]))
            for bid in self._ids}
        for bid in self._ids:
            d = _dist(before[bid][0], after[bid][0])
            if d > cfg.settle_report:
                dz = after[bid][0][2] - before[bid][0][2]
                what = "dropped onto its support" if dz < -0.7 * d else "shifted while settling"
                repairs.append(f"box {bid!r} {what}: moved {d:.3f} m")
        for msg in repairs:
            warnings.warn(f"scene repaired: {msg}", stacklevel=2)
        self.repairs: tuple[str, ...] = tuple(repairs)
        if local:
            for i, bid in enumerate(self._ids):
                self._twin[bid] = self._add_twin(bid, i)
        self._twin_of = {v: k for k, v in self._twin.items()}
        snap = self.snapshot()   # start every world from a canonical state (see `restore`)
        self.restore(snap)
        self.forget(snap)
        self.scene: Scene = scene.with_boxes(
            replace(b, position=after[b.id][0], orientation=after[b.id][1]) for b in scene.boxes)

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

    # ----------------------------------------------------------------- repair
    def _penetrations(self) -> list[tuple[float, str, str | None, tuple, int]]:
        """(depth, box, other box or None, normal pointing out of the other, other body).

        Overlaps under `repair_min_overlap` are left to the contact solver: a settled
        Bullet stack rests ~1 mm deep in its contacts, and "repairing" that on every
        reload of a settled scene would only lift boxes that then drop back.
        """
        p = self._p
        eps = -self.config.repair_min_overlap
        out = []
        ids = self._ids
        aabb = {bid: p.getAABB(self._body[bid]) for bid in ids}

        def overlaps(a, b) -> bool:
            return all(a[0][k] < b[1][k] and b[0][k] < a[1][k] for k in range(3))

        for i, a in enumerate(ids):
            ba = self._body[a]
            for sbody, sname in self._static.items():
                if sname == "ground":
                    continue
                if not overlaps(aabb[a], p.getAABB(sbody)):
                    continue
                for c in p.getClosestPoints(ba, sbody, 0.0):
                    if c[8] < eps:
                        out.append((-c[8], a, None, tuple(c[7]), sbody))
            for b in ids[i + 1:]:
                if not overlaps(aabb[a], aabb[b]):
                    continue
                cs = p.getClosestPoints(ba, self._body[b], 0.0)
                if cs:
                    c = min(cs, key=lambda c: c[8])
                    if c[8] < eps:
                        out.append((-c[8], a, b, tuple(c[7]), self._body[b]))
        return out

    def _repair_overlaps(self) -> list[str]:
        """Push apart overlaps up to the tolerance; refuse deeper ones (SceneError)."""
        tol = self.config.repair_tolerance
        p = self._p
        pens = self._penetrations()
        for depth, a, b, _, sbody in sorted(pens, key=lambda x: -x[0]):
            if depth > tol:
                other = f"box {b!r}" if b else f"the shelf's {self._static[sbody]}"
                self.close()
                raise SceneError(f"box {a!r} and {other} overlap by {depth:.3f} m "
                                 f"(more than the {tol:.3f} m that can be repaired)")
        moved: dict[str, list] = {}
        for _ in range(30):
            if not pens:
                break
            for depth, a, b, n, _ in pens:
                # normal points from the other body to `a`: moving a along n separates them.
                if b is None:
                    self._shift(a, n, depth, "the shelf", moved)
                elif abs(n[2]) > 0.5:
                    # stacked: lift the upper box only
                    za = self._raw_poses((a,))[a][0][2]
                    zb = self._raw_poses((b,))[b][0][2]
                    if za >= zb:
                        self._shift(a, n, depth, b, moved)
                    else:
                        self._shift(b, tuple(-x for x in n), depth, a, moved)
                else:
                    self._shift(a, n, depth / 2, b, moved)
                    self._shift(b, tuple(-x for x in n), depth / 2, a, moved)
            pens = self._penetrations()
        if pens:
            worst = max(pens, key=lambda x: x[0])
            raise SceneError(f"box {worst[1]!r} overlaps {worst[2] or 'the shelf'} and the overlap "
                             f"cannot be repaired")
        msgs = []
        for bid in self._ids:
            if bid in moved:
                off, others = moved[bid]
                d = _norm(off)
                if d > 1e-4:
                    msgs.append(f"box {bid!r} moved {d:.3f} m by ({off[0]:+.3f}, {off[1]:+.3f}, "
                                f"{off[2]:+.3f}) to undo its overlap with {', '.join(others)}")
        _ = p
        return msgs

    def _shift(self, bid: str, n: tuple, d: float, other: str, moved: dict) -> None:
        p = self._p
        body = self._body[bid]
        pos, orn = p.getBasePositionAndOrientation(body)
        step = tuple(n[k] * (d + 2e-4) for k in range(3))
        p.resetBasePositionAndOrientation(body, [pos[k] + step[k] for k in range(3)], orn)
        off, others = moved.setdefault(bid, [(0.0, 0.0, 0.0), []])
        moved[bid][0] = tuple(off[k] + step[k] for k in range(3))
        name = repr(other) if other != "the shelf" else other
        if name not in others:
            others.append(name)

    # ---------------------------------------------------------------- queries
    def _raw_poses(self, ids) -> dict[str, tuple[Vec3, Quat]]:
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
            if pos[2] > -0.02:
                out.append(bid)
        return tuple(out)

    def poses(self) -> dict[str, tuple[Vec3, Quat]]:
        return self._raw_poses(self.present())

    def _active(self) -> list[str]:
        return [b for b in self._ids if b not in self._parked]

    def _moving(self) -> list[str]:
        cfg, p = self.config, self._p
        out = []
        for bid in self._active():
            if bid in self._frozen:
                continue
            lin, ang = p.getBaseVelocity(self._body[bid])
            if _norm(lin) > cfg.rest_velocity or _norm(ang) > cfg.rest_angular_velocity:
                out.append(bid)
        return out

    # --------------------------------------------------------------- stepping
    def _step(self) -> None:
        self._p.stepSimulation()
        self.sim_time += self.config.time_step

    def _settle(self, max_time: float) -> bool:
        """Step until every box on the shelf rests for `rest_window`; False if it never does."""
        cfg = self.config
        need = max(1, int(round(cfg.rest_window / cfg.time_step)))
        calm = 0
        for _ in range(int(math.ceil(max_time / cfg.time_step))):
            self._step()
            calm = calm + 1 if not self._moving() else 0
            if calm >= need:
                return True
        return False

    def nudge(self, spin: float) -> dict[str, tuple[float, float]]:
        """How far (m, deg) each box ends up after a small knock, the world put back after.

        Every box on the shelf is set turning at `spin` rad/s about a horizontal axis
        (alternating x and y from box to box), then the world settles. A box at rest in
        a stable pose rocks back; one balanced on an edge (an unstable equilibrium the
        solver would otherwise keep forever) falls over.
        """
        p = self._p
        ids = self.present()
        before = self._raw_poses(ids)
        snap = self.snapshot()
        t = self.sim_time
        try:
            for i, bid in enumerate(ids):
                axis = (spin, 0.0, 0.0) if i % 2 else (0.0, spin, 0.0)
                p.resetBaseVelocity(self._body[bid], [0.0, 0.0, 0.0], list(axis))
            self._settle(self.config.settle_time)
            after = self._raw_poses(ids)
        finally:
            self.restore(snap)
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
        before = self._raw_poses(ids)
        for _ in range(int(math.ceil(seconds / self.config.time_step))):
            self._step()
        after = self._raw_poses(ids)
        return {b: math.dist(before[b][0], after[b][0]) for b in ids}

    def _park(self, bid: str) -> None:
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

    def _free_lift(self, box_id: str) -> float:
        """How far the gripper may lift `box_id`: `pull_lift`, capped by the free space above it.

        Anything whose bounding box overlaps this box's footprint and starts above its
        top (another box, the shelf's top) bounds the lift; 2 mm are kept free.
        """
        p, cfg = self._p, self.config
        lo, hi = p.getAABB(self._body[box_id])
        gap = cfg.pull_lift + 0.002
        shrink = 0.003
        others = [self._body[b] for b in self._active() if b != box_id]
        others += [b for b, name in self._static.items() if name == "top"]
        for ob in others:
            olo, ohi = p.getAABB(ob)
            if (olo[0] < hi[0] - shrink and lo[0] + shrink < ohi[0] and olo[1] < hi[1] - shrink
                    and lo[1] + shrink < ohi[1] and ohi[2] > hi[2]):
                gap = min(gap, olo[2] - hi[2])
        return max(0.0, min(cfg.pull_lift, gap - 0.002))

    # --------------------------------------------------------------- locality
    def neighbourhood(self, seeds, *, corridor: bool = False) -> set[str]:
        """The boxes a change at `seeds` can move before the step is decided.

        - the seeds and every box whose bounding box comes within `local_margin`
          of a seed's;
        - with `corridor` (a pull), every box in front of a seed that overlaps it
          in x and z (within the margin): the box and the gripper travel there;
        - what the seeds stand on, down to the floor (a fragile column under the
          pulled box rocks with it);
        - everything stacked on any of those, up to the top;
        - the direct supports of all of those (a box bridging two columns
          pivots on both).

        A box stands on another when its bottom is at the other's top, within
        3 cm for tilt, and their footprints overlap by 5 mm. The rest of the
        shelf can only move once some box here has moved a lot, and by then the
        step has collapsed (docs/physics.md, "Local trials").
        """
        p, m = self._p, self.config.local_margin
        act = self._active()
        box = {b: p.getAABB(self._body[b]) for b in act}
        keep = {s for s in seeds if s in box}

        def near(a, c) -> bool:
            return (a[0][0] - m < c[1][0] and c[0][0] - m < a[1][0] and a[0][1] - m < c[1][1]
                    and c[0][1] - m < a[1][1] and a[0][2] - m < c[1][2] and c[0][2] - m < a[1][2])

        def in_front(a, c) -> bool:
            return (a[0][0] - m < c[1][0] and c[0][0] - m < a[1][0] and a[0][2] - m < c[1][2]
                    and c[0][2] - m < a[1][2] and c[0][1] < a[0][1])

        def stands_on(c, d) -> bool:
            ov = 0.005
            return (c[0][0] < d[1][0] - ov and d[0][0] < c[1][0] - ov and c[0][1] < d[1][1] - ov
                    and d[0][1] < c[1][1] - ov and d[1][2] - 0.03 < c[0][2] < d[1][2] + m)

        seed_boxes = [box[s] for s in keep]
        keep |= {c for c in act if any(near(a, box[c]) or (corridor and in_front(a, box[c]))
                                       for a in seed_boxes)}
        down = set(keep & set(seeds))
        todo = list(down)
        while todo:
            c = box[todo.pop()]
            for d in act:
                if d not in down and stands_on(c, box[d]):
                    down.add(d)
                    todo.append(d)
        keep |= down
        todo = [b for b in act if b in keep]
        while todo:
            d = box[todo.pop()]
            for c in act:
                if c not in keep and stands_on(box[c], d):
                    keep.add(c)
                    todo.append(c)
        keep |= {d for d in act if d not in keep and any(stands_on(box[c], box[d]) for c in keep)}
        return keep

    def _freeze(self, keep) -> None:
        """Every box on the shelf outside `keep` stands in as a static copy of itself.

        Its dynamic body leaves the broadphase (it falls freely, touching nothing,
        and costs the solver nothing); `_thaw` puts it back as it was (the position
        bit for bit, the quaternion to its last bit: Bullet round-trips it).
        """
        p = self._p
        for bid in self._active():
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
        self._park(box_id)
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
                self._park(b)
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
        p.resetBasePositionAndOrientation(self._gripper, list(_GRIPPER_PARK), [0, 0, 0, 1])
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
        import random

        p, cfg = self._p, self.config
        dt = cfg.time_step
        rng = random.Random(f"shelfpick-pull:{int(seed)}:{box_id}")
        body = self._body[box_id]
        frozen = self._frozen
        others = [b for b in self._active() if b != box_id and b not in frozen]
        obody = [self._body[b] for b in others]
        bodies_to_box = {self._body[b]: b for b in others}
        bodies_to_box.update({self._twin[b]: b for b in frozen})
        start = [p.getBasePositionAndOrientation(ob) for ob in obody]
        onset: dict[str, int] = {}
        collapse_at: dict[str, int] = {}
        touched: set[str] = set()
        frames: list[Frame] = []
        frame_every = max(1, int(round(1.0 / (30.0 * dt))))
        rest_need = max(1, int(round(cfg.rest_window / dt)))
        every = max(1, int(cfg.monitor_every))

        pos0, orn0 = p.getBasePositionAndOrientation(body)
        r0 = quat_to_matrix(xyzw_to_wxyz(orn0))
        hx, hy, hz = self._half[box_id]
        front_local = (0.0, -hy, 0.0)
        fw = _matvec(r0, front_local)
        front0 = (pos0[0] + fw[0], pos0[1] + fw[1], pos0[2] + fw[2])
        # extent of the box along world y from its centre (for "clear of the shelf front")
        ext_y = abs(r0[1][0]) * hx + abs(r0[1][1]) * hy + abs(r0[1][2]) * hz
        travel_needed = (pos0[1] + ext_y) + cfg.pull_margin
        gh = cfg.gripper_size[1] / 2
        grip_local = (0.0, -hy - gh - 1e-3, 0.0)
        weight = p.getDynamicsInfo(body, -1)[0] * cfg.gravity
        force_eps = 0.05 * weight
        # a drive far stronger than the boxes' weights turns Bullet's edge contacts into
        # catapults (a 50 N drive on an 8 g box flings the box below it); a suction
        # gripper's pull is bounded anyway
        max_force = min(cfg.pull_force, cfg.pull_force_weights * weight)
        clear_need = max(1, int(round(cfg.clear_time / dt)))

        # the drive holds x, y and the orientation (a stiff arm) but leaves z free: the
        # box rides on its support with its own weight, as a dragged box does. A drive
        # that also held z would press the box into the one below it with up to the
        # force limit at every vertical jitter, and tip that box over (see docs/physics.md).
        # a suction gripper grasps, lifts a few mm, then pulls: a box with free space above it
        # is lifted off its support (and then held at that height), so it no longer drags the
        # box below it along by friction. A box that something rests on gets no lift (the
        # free space above it is nil) and is dragged as before, z free.
        lift = self._free_lift(box_id) if cfg.pull_lift > 0 else 0.0
        lift_steps = int(math.ceil(cfg.lift_time / dt)) if lift > 0 else 0
        joint = p.JOINT_FIXED if (lift > 0 or cfg.pull_hold) else p.JOINT_PRISMATIC
        cid = p.createConstraint(body, -1, -1, -1, joint, [0, 0, 1], list(front_local),
                                 list(front0), [0, 0, 0, 1], list(orn0))
        p.changeConstraint(cid, list(front0), jointChildFrameOrientation=list(orn0),
                           maxForce=max_force)
        p.setCollisionFilterPair(self._gripper, body, -1, -1, 0)

        def place_gripper() -> tuple:
            pos, orn = p.getBasePositionAndOrientation(body)
            r = quat_to_matrix(xyzw_to_wxyz(orn))
            g = _matvec(r, grip_local)
            p.resetBasePositionAndOrientation(self._gripper, [pos[0] + g[0], pos[1] + g[1], pos[2] + g[2]],
                                              orn)
            return pos

        step = 0

        def monitor() -> bool:
            """Check every other box; True while something still moves."""
            moving = False
            for k, ob in enumerate(obody):
                bid = others[k]
                pos, orn = p.getBasePositionAndOrientation(ob)
                lin, ang = p.getBaseVelocity(ob)
                v = _norm(lin)
                w = _norm(ang)
                if v > cfg.rest_velocity or w > cfg.rest_angular_velocity:
                    moving = True
                if bid in collapse_at:
                    continue
                d = _dist(pos, start[k][0])
                if bid not in onset and (d > cfg.onset_displacement or v > cfg.onset_velocity):
                    onset[bid] = step
                # certain collapses only: a tall column may rock a couple of cm and come
                # back, so the end-of-step displacement is judged after the step; and
                # back; a velocity spike counts once the box has also really moved (a jolt
                # from a contact that leaves the box where it was is not a collapse)
                a = _rot_angle_deg(orn, start[k][1])
                fast = v > cfg.collapse_velocity or w > cfg.collapse_angular_velocity
                if (d > cfg.collapse_peak_displacement or a > cfg.collapse_peak_rotation
                        or (fast and (d > cfg.collapse_displacement / 2 or a > cfg.collapse_rotation / 2))):
                    collapse_at[bid] = step
                    onset.setdefault(bid, step)
            return moving

        def record_frame(include_pulled: bool) -> None:
            ids = others + ([box_id] if include_pulled else [])
            t = round(step * dt, 4)
            frames.append((t, {b: (tuple(round(x, 5) for x in pp), tuple(round(x, 6) for x in qq))
                               for b, (pp, qq) in self._raw_poses(ids).items()}))

        extracted = False
        note = ""
        try:
            if record:
                record_frame(True)
            place_gripper()
            ramp = max(cfg.pull_ramp, dt)
            dist = 0.0
            period = max(1, int(round(cfg.disturbance_period / dt)))
            jx = jz = 0.0
            tx = tz = 0.0
            free_steps = 0
            pos = pos0
            max_steps = int(math.ceil(cfg.pull_timeout / dt))
            while True:
                z = front0[2]
                if step < lift_steps:
                    z += lift * (step + 1) / lift_steps
                else:
                    z += lift
                    t = (step - lift_steps) * dt
                    speed = cfg.pull_speed * min(1.0, (t + dt) / ramp)
                    dist = min(travel_needed + 0.01, dist + speed * dt)
                if step % period == 0:
                    tx = rng.uniform(-cfg.disturbance, cfg.disturbance)
                    tz = rng.uniform(-cfg.disturbance_force, cfg.disturbance_force) * weight
                jx += (tx - jx) * 0.3
                jz += (tz - jz) * 0.3
                target = [front0[0] + jx, front0[1] - dist, z]
                p.changeConstraint(cid, target, jointChildFrameOrientation=list(orn0),
                                   maxForce=max_force)
                if jz:
                    p.applyExternalForce(body, -1, [0.0, 0.0, jz], list(pos), p.WORLD_FRAME)
                self._step()
                step += 1
                pos = place_gripper()
                if step % every == 0:
                    monitor()
                # contacts of the pulled box and the gripper with other boxes
                engaged = False
                for c in p.getContactPoints(bodyA=body):
                    other = bodies_to_box.get(c[2])
                    if other is None or c[8] > 1e-3:
                        continue
                    if abs(c[7][2]) > 0.5 or c[9] > force_eps:
                        engaged = True
                    if abs(c[7][2]) <= 0.5:
                        touched.add(other)
                for c in p.getContactPoints(bodyA=self._gripper):
                    other = bodies_to_box.get(c[2])
                    if other is not None and c[8] <= 1e-3:
                        touched.add(other)
                        engaged = True
                if record and step % frame_every == 0:
                    record_frame(True)
                if stop_on_collapse and collapse_at:
                    note = "stopped at the first collapse"
                    break
                travelled = pos0[1] - pos[1]
                out = pos[1] + ext_y < -cfg.pull_margin
                free_steps = 0 if engaged else free_steps + 1
                if out or (cfg.early_clear and travelled > 0.01 and free_steps >= clear_need):
                    extracted = True
                    break
                if step >= max_steps:
                    note = f"stuck: the box did not come out within {cfg.pull_timeout:g} s"
                    break
        finally:
            p.removeConstraint(cid)
            p.setCollisionFilterPair(self._gripper, body, -1, -1, 1)
            p.resetBasePositionAndOrientation(self._gripper, list(_GRIPPER_PARK), [0, 0, 0, 1])
        if extracted:
            self._park(box_id)
        if not (stop_on_collapse and collapse_at):
            # let the rest settle, watching for collapses
            calm = 0
            for _ in range(int(math.ceil(cfg.settle_time / dt))):
                self._step()
                step += 1
                if step % every == 0:
                    calm = calm + every if not monitor() else 0
                if record and step % frame_every == 0:
                    record_frame(not extracted)
                if stop_on_collapse and collapse_at:
                    note = "stopped at the first collapse"
                    break
                if calm >= rest_need:
                    break
        if record:
            record_frame(not extracted)

        end = {b: p.getBasePositionAndOrientation(self._body[b]) for b in others}
        disp = {b: _dist(end[b][0], start[k][0]) for k, b in enumerate(others)}
        rot = {b: _rot_angle_deg(end[b][1], start[k][1]) for k, b in enumerate(others)}
        if frozen:   # they stood still, as static copies of themselves
            disp = {b: disp.get(b, 0.0) for b in self._active() if b != box_id}
            rot = {b: rot.get(b, 0.0) for b in disp}
        for b in others:
            if b not in collapse_at and (disp[b] > cfg.collapse_displacement
                                         or rot[b] > cfg.collapse_rotation):
                collapse_at[b] = step
                onset.setdefault(b, step)
        order = {b: i for i, b in enumerate(self._ids)}
        moved = tuple(sorted(onset, key=lambda b: (onset[b], order[b])))
        collapsed = tuple(b for b in moved if b in collapse_at)
        collided = tuple(b for b in others if b in touched
                         and (disp[b] > cfg.collision_threshold or b in collapse_at))
        return StepResult(box_id, extracted, collapsed, collided, disp, rot, moved,
                          tuple(frames), round(step * dt, 6), note)

    def close(self) -> None:
        if getattr(self, "_p", None) is not None:
            try:
                _release(self._p, getattr(self, "_gui", True))
            except Exception:  # already gone
                pass
            self._p = None  # type: ignore[assignment]

    def __enter__(self) -> "ShelfSim":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        self.close()
