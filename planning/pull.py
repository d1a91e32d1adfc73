"""One suction pull of one box in a `ShelfSim`, and the verdict on what the rest did.

The gripper grasps the front face, lifts the box a few mm when there is free
space above it (else drags it on its support), and pulls it straight out along
-y at the configured speed, with a seeded vibration. The drive holds the face's
place across the shelf, its place along the pull and the box's orientation; a
held height is rigid or (`hold_spring`) a spring with a bounded force (`_Height`),
as a compliant suction cup's is. A `CollapseMonitor`
watches every other box from the settled start of the step: when it started
moving, and when a collapse became certain. What the box and the gripper
touched on the way is a collision when that neighbour then moved.
"""
from __future__ import annotations

import math
import random
from typing import Iterable, Protocol, runtime_checkable

from shelfpick.perception.scene import Quat, Vec3, quat_to_matrix, xyzw_to_wxyz
from shelfpick.planning.bullet_clients import Client
from shelfpick.planning.geometry3 import dist, matvec, norm, rot_angle_deg
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.step_result import Frame, StepResult


@runtime_checkable
class PullWorld(Protocol):
    """What a pull needs of the world it runs in: `ShelfSim`'s members "for a pull trial".
    Declared here, by the pull, so that this module does not import the simulation that calls it
    (`ShelfSim.remove` runs `pull(self, ...)`)."""

    @property
    def client(self) -> Client: ...
    @property
    def config(self) -> PhysicsConfig: ...
    @property
    def ids(self) -> tuple[str, ...]: ...
    @property
    def gripper_body(self) -> int: ...
    def body(self, box_id: str) -> int: ...
    def half_extents(self, box_id: str) -> tuple[float, float, float]: ...
    def frozen_twins(self) -> dict[str, int]: ...
    def active(self) -> list[str]: ...
    def free_lift(self, box_id: str) -> float: ...
    def raw_poses(self, ids: Iterable[str]) -> dict[str, tuple[Vec3, Quat]]: ...
    def step(self) -> None: ...
    def park(self, bid: str) -> None: ...
    def park_gripper(self) -> None: ...


class CollapseMonitor:
    """The other boxes of a step: when each started moving, and when its collapse became certain."""

    def __init__(self, sim: PullWorld, others: list[str]) -> None:
        self.p, self.cfg = sim.client, sim.config
        self.others = others
        self.bodies = [sim.body(b) for b in others]
        self.start = [self.p.getBasePositionAndOrientation(ob) for ob in self.bodies]
        # each box's tipping angle, read only by `peak_tipping` verdicts (off by default: not computed)
        self.tip = ([max(self.cfg.collapse_peak_rotation, _tipping_angle(sim.half_extents(b), orn))
                     for b, (_, orn) in zip(others, self.start)] if self.cfg.peak_tipping else [])
        self.onset: dict[str, int] = {}
        self.collapse_at: dict[str, int] = {}

    def look(self, step: int) -> bool:
        """Check every other box at `step`; True while something still moves."""
        p, cfg = self.p, self.cfg
        pose, velocity = p.getBasePositionAndOrientation, p.getBaseVelocity
        rest_v, rest_w = cfg.rest_velocity, cfg.rest_angular_velocity
        moving = False
        for k, ob in enumerate(self.bodies):
            bid = self.others[k]
            lin, ang = velocity(ob)
            v = norm(lin)
            w = norm(ang)
            if v > rest_v or w > rest_w:
                moving = True
            if bid in self.collapse_at:
                continue     # (its pose is no longer read: a query, it changes nothing)
            pos, orn = pose(ob)
            d = dist(pos, self.start[k][0])
            if bid not in self.onset and (d > cfg.onset_displacement or v > cfg.onset_velocity):
                self.onset[bid] = step
            if self._certain(k, d, rot_angle_deg(orn, self.start[k][1]), v, w):
                self.collapse_at[bid] = step
                self.onset.setdefault(bid, step)
        return moving

    def _certain(self, k: int, d: float, a: float, v: float, w: float) -> bool:
        """Whether box `k`, moved `d` m and turned `a` deg at speeds `v`, `w`, has surely collapsed;
        the rest is judged at the end of the step."""
        cfg = self.cfg
        fast = v > cfg.collapse_velocity or w > cfg.collapse_angular_velocity
        if not cfg.peak_tipping:
            # a tall column may rock a couple of cm and come back; a velocity spike counts once
            # the box has also really moved (a jolt that leaves the box where it was is not one)
            return (d > cfg.collapse_peak_displacement or a > cfg.collapse_peak_rotation
                    or (fast and (d > cfg.collapse_displacement / 2 or a > cfg.collapse_rotation / 2)))
        # a box that tips and falls back (lifted 25 deg by a drag off it: its centre 5-11 cm away,
        # back to within mm) is a wobble: certain only past its tipping angle, or slid level
        # (turned < half the end threshold) past the peak, or fast while it slid past the end's
        level = a < cfg.collapse_rotation / 2
        return (a > self.tip[k] or (level and d > cfg.collapse_peak_displacement)
                or (level and fast and d > cfg.collapse_displacement))

    def judge_end(self, step: int) -> tuple[dict[str, float], dict[str, float]]:
        """Displacement and rotation of every other box from the step's start to now; a box past
        the end-of-step thresholds has collapsed."""
        p, cfg = self.p, self.cfg
        end = [p.getBasePositionAndOrientation(ob) for ob in self.bodies]
        disp = {b: dist(end[k][0], self.start[k][0]) for k, b in enumerate(self.others)}
        rot = {b: rot_angle_deg(end[k][1], self.start[k][1]) for k, b in enumerate(self.others)}
        for b in self.others:
            if b not in self.collapse_at and (disp[b] > cfg.collapse_displacement
                                              or rot[b] > cfg.collapse_rotation):
                self.collapse_at[b] = step
                self.onset.setdefault(b, step)
        return disp, rot


def _tipping_angle(half: tuple[float, float, float], orn: Quat) -> float:
    """Degrees a box must turn about a bottom edge before its centre passes over that edge (it
    falls on, it cannot come back): atan(half width / half height), the smaller of its two ways
    over, with the box's up axis the one closest to the world's."""
    r = quat_to_matrix(xyzw_to_wxyz(orn))
    up = max(range(3), key=lambda j: abs(r[2][j]))
    side = min(half[j] for j in range(3) if j != up)
    return math.degrees(math.atan2(side, half[up]))


class _SetPoint:
    """Where the drive holds the front face (with `pull_turn` the centre) at each step: up by the lift first, then out along -y
    (speed ramped up over `pull_ramp`), plus the seeded, smoothed vibration of a real arm
    (a sideways offset `jx`, and a vertical force `jz` the caller applies)."""

    def __init__(self, front0: tuple, lift: float, lift_steps: int, travel_needed: float, cfg, rng: random.Random,
                 weight: float) -> None:
        self.front0, self.lift, self.lift_steps, self.travel_needed = front0, lift, lift_steps, travel_needed
        self.cfg, self.rng, self.weight = cfg, rng, weight
        self.ramp = max(cfg.pull_ramp, cfg.time_step)
        self.period = max(1, int(round(cfg.disturbance_period / cfg.time_step)))
        self.dist = 0.0
        self.jx = self.jz = self.tx = self.tz = 0.0

    def at(self, step: int) -> list[float]:
        cfg, dt = self.cfg, self.cfg.time_step
        z = self.front0[2]
        if step < self.lift_steps:
            z += self.lift * (step + 1) / self.lift_steps
        else:
            z += self.lift
            t = (step - self.lift_steps) * dt
            speed = cfg.pull_speed * min(1.0, (t + dt) / self.ramp)
            self.dist = min(self.travel_needed + 0.01, self.dist + speed * dt)
        if step % self.period == 0:
            self.tx = self.rng.uniform(-cfg.disturbance, cfg.disturbance)
            self.tz = self.rng.uniform(-cfg.disturbance_force, cfg.disturbance_force) * self.weight
        self.jx += (self.tx - self.jx) * cfg.disturbance_smoothing
        self.jz += (self.tz - self.jz) * cfg.disturbance_smoothing
        return [self.front0[0] + self.jx, self.front0[1] - self.dist, z]


class _Height:
    """The vertical force of a drive that holds the box's height (lift, or `pull_hold`): a damped
    spring towards the set point, plus the box's weight once it is lifted, bounded by what a
    compliant suction cup on a vertical face can do: carry the box, but press it down at most
    `hold_down_weights` (a rigid hold pressed a top box into the one below with 5-17 weights)."""

    def __init__(self, cfg: PhysicsConfig, mass: float, carry: float) -> None:
        """`carry`: the share of the box's weight the drive carries (1 lifted; `hold_carry` dragged)."""
        self.k, self.c = cfg.hold_stiffness * mass, cfg.hold_damping * mass
        weight = mass * cfg.gravity
        self.carry = carry * weight
        self.low, self.high = -cfg.hold_down_weights * weight, cfg.hold_up_weights * weight

    def force(self, error: float, vz: float, extra: float) -> float:
        """Upward force for a height `error` (set point minus height, m) and vertical speed `vz`."""
        f = self.carry + self.k * error - self.c * vz + extra
        return max(self.low, min(self.high, f))


class PullTrial:
    """The state of one pull: the drive's target, the vibration, the contacts, the frames."""

    def __init__(self, sim: PullWorld, box_id: str, seed: int, record: bool) -> None:
        self.sim, self.box_id, self.record = sim, box_id, record
        p, cfg = sim.client, sim.config
        self.p, self.cfg = p, cfg
        dt = cfg.time_step
        self.rng = random.Random(f"shelfpick-pull:{int(seed)}:{box_id}")
        self.body = sim.body(box_id)
        twins = sim.frozen_twins()
        self.others = [b for b in sim.active() if b != box_id and b not in twins]
        self.body_box = {sim.body(b): b for b in self.others}
        self.body_box.update({t: b for b, t in twins.items()})
        self.frozen = bool(twins)
        self.monitor = CollapseMonitor(sim, self.others)
        self.touched: set[str] = set()
        self.frames: list[Frame] = []
        self.step = 0
        self.frame_every = max(1, int(round(1.0 / (cfg.record_fps * dt))))
        self.rest_need = max(1, int(round(cfg.rest_window / dt)))
        self.every = max(1, int(cfg.monitor_every))
        self.note = ""
        self._geometry(sim)

    def _geometry(self, sim: PullWorld) -> None:
        p, cfg, dt = self.p, self.cfg, self.cfg.time_step
        self.pos0, self.orn0 = p.getBasePositionAndOrientation(self.body)
        pos0 = self.pos0
        r0 = quat_to_matrix(xyzw_to_wxyz(self.orn0))
        hx, hy, hz = sim.half_extents(self.box_id)
        self.front_local = (0.0, -hy, 0.0)
        fw = matvec(r0, self.front_local)
        self.front0 = (pos0[0] + fw[0], pos0[1] + fw[1], pos0[2] + fw[2])
        # extent of the box along world y from its centre (for "clear of the shelf front")
        self.ext_y = abs(r0[1][0]) * hx + abs(r0[1][1]) * hy + abs(r0[1][2]) * hz
        self.travel_needed = (pos0[1] + self.ext_y) + cfg.pull_margin
        gh = cfg.gripper_size[1] / 2
        self.grip_local = (0.0, -hy - gh - cfg.gripper_gap, 0.0)
        self.mass = p.getDynamicsInfo(self.body, -1)[0]
        self.weight = self.mass * cfg.gravity
        self.up_local = (r0[2][0], r0[2][1], r0[2][2])   # world up in the box's frame: the free axis
        self.force_eps = cfg.engage_force_weights * self.weight
        # a drive far stronger than the boxes' weights turns Bullet's edge contacts into
        # catapults (a 50 N drive on an 8 g box flings the box below it); a suction
        # gripper's pull is bounded anyway
        self.max_force = min(cfg.pull_force, cfg.pull_force_weights * self.weight)
        self.clear_need = max(1, int(round(cfg.clear_time / dt)))
        # a box with free space above it is lifted off its support (then held at that height), so
        # it no longer drags the box below it along by friction; a box something rests on gets no
        # lift and is dragged. The drive holds x, y and the orientation (a stiff arm); the height,
        # when lifted or `pull_hold`, is held rigidly by the joint or, with `hold_spring`, by a
        # bounded spring (`_Height`); else it is free: the box rides on its support
        self.lift = sim.free_lift(self.box_id) if cfg.pull_lift > 0 else 0.0
        self.lift_steps = int(math.ceil(cfg.lift_time / dt)) if self.lift > 0 else 0

    # ------------------------------------------------------------------ the pull
    def _place_gripper(self) -> tuple:
        p = self.p
        pos, orn = p.getBasePositionAndOrientation(self.body)
        r = quat_to_matrix(xyzw_to_wxyz(orn))
        g = matvec(r, self.grip_local)
        p.resetBasePositionAndOrientation(self.sim.gripper_body,
                                          [pos[0] + g[0], pos[1] + g[1], pos[2] + g[2]], orn)
        return pos

    def record_frame(self, include_pulled: bool) -> None:
        ids = self.others + ([self.box_id] if include_pulled else [])
        t = round(self.step * self.cfg.time_step, 4)
        self.frames.append((t, {b: (tuple(round(x, 5) for x in pp), tuple(round(x, 6) for x in qq))
                                for b, (pp, qq) in self.sim.raw_poses(ids).items()}))

    def _engaged(self) -> bool:
        """Record what the box and the gripper touch; True while something leans on, or drags, the box."""
        p, slop, up = self.p, self.cfg.contact_slop, self.cfg.support_normal
        engaged = False
        for c in p.getContactPoints(bodyA=self.body):
            other = self.body_box.get(c[2])
            if other is None or c[8] > slop:
                continue
            if abs(c[7][2]) > up or c[9] > self.force_eps:
                engaged = True
            if abs(c[7][2]) <= up:
                self.touched.add(other)
        for c in p.getContactPoints(bodyA=self.sim.gripper_body):
            other = self.body_box.get(c[2])
            if other is not None and c[8] <= slop:
                self.touched.add(other)
                engaged = True
        return engaged

    def drive(self, stop_on_collapse: bool) -> bool:
        """Pull until the box is out (True), stuck, or (with `stop_on_collapse`) something collapsed."""
        p, cfg = self.p, self.cfg
        held = self.lift > 0 or cfg.pull_hold
        # the held height as a bounded spring (`hold_spring`), or as the joint itself (rigid)
        spring = held and cfg.hold_spring
        # `pull_turn` (off by default): the box may turn, the arm holds its centre (point to point)
        turn = held and not spring and cfg.pull_turn
        joint = p.JOINT_POINT2POINT if turn else p.JOINT_FIXED if held and not spring else p.JOINT_PRISMATIC
        axis = list(self.up_local) if spring else [0, 0, 1]
        local, start = ((0.0, 0.0, 0.0), self.pos0) if turn else (self.front_local, self.front0)
        cid = p.createConstraint(self.body, -1, -1, -1, joint, axis, list(local),
                                 list(start), [0, 0, 0, 1], list(self.orn0))
        p.changeConstraint(cid, list(start), jointChildFrameOrientation=list(self.orn0),
                           maxForce=self.max_force)
        p.setCollisionFilterPair(self.sim.gripper_body, self.body, -1, -1, 0)
        try:
            if self.record:
                self.record_frame(True)
            self._place_gripper()
            set_point = _SetPoint(start, self.lift, self.lift_steps, self.travel_needed, cfg,
                                  self.rng, self.weight)
            height = _Height(cfg, self.mass, 1.0 if self.lift > 0 else cfg.hold_carry) if spring else None
            dz = self.front0[2] - self.pos0[2]   # the face's height above the centre (orientation held)
            free_steps = 0
            pos = self.pos0
            max_steps = int(math.ceil(cfg.pull_timeout / cfg.time_step))
            world = p.WORLD_FRAME   # a constant, looked up once (the client resolves each name per call)
            while True:
                target = set_point.at(self.step)
                p.changeConstraint(cid, target, jointChildFrameOrientation=list(self.orn0),
                                   maxForce=self.max_force)
                fz = set_point.jz
                if height is not None:
                    fz = height.force(target[2] - pos[2] - dz, p.getBaseVelocity(self.body)[0][2], fz)
                if fz:
                    p.applyExternalForce(self.body, -1, [0.0, 0.0, fz], list(pos), world)
                pos, engaged = self._one_step()
                if stop_on_collapse and self.monitor.collapse_at:
                    self.note = "stopped at the first collapse"
                    return False
                travelled = self.pos0[1] - pos[1]
                out = pos[1] + self.ext_y < -cfg.pull_margin
                free_steps = 0 if engaged else free_steps + 1
                if out or (cfg.early_clear and travelled > 0.01 and free_steps >= self.clear_need):
                    return True
                if self.step >= max_steps:
                    self.note = f"stuck: the box did not come out within {cfg.pull_timeout:g} s"
                    return False
        finally:
            p.removeConstraint(cid)
            p.setCollisionFilterPair(self.sim.gripper_body, self.body, -1, -1, 1)
            self.sim.park_gripper()

    def _one_step(self) -> tuple[tuple, bool]:
        """One physics step of the pull: (the box's position, whether something is engaged with it)."""
        self.sim.step()
        self.step += 1
        pos = self._place_gripper()
        if self.step % self.every == 0:
            self.monitor.look(self.step)
        engaged = self._engaged()
        if self.record and self.step % self.frame_every == 0:
            self.record_frame(True)
        return pos, engaged

    def settle(self, stop_on_collapse: bool, extracted: bool) -> None:
        """Let the rest settle after the pull, watching for collapses."""
        calm = 0
        for _ in range(int(math.ceil(self.cfg.settle_time / self.cfg.time_step))):
            self.sim.step()
            self.step += 1
            if self.step % self.every == 0:
                calm = calm + self.every if not self.monitor.look(self.step) else 0
            if self.record and self.step % self.frame_every == 0:
                self.record_frame(not extracted)
            if stop_on_collapse and self.monitor.collapse_at:
                self.note = "stopped at the first collapse"
                break
            if calm >= self.rest_need:
                break

    def result(self, extracted: bool) -> StepResult:
        mon, cfg = self.monitor, self.cfg
        disp, rot = mon.judge_end(self.step)
        if self.frozen:   # they stood still, as static copies of themselves
            disp = {b: disp.get(b, 0.0) for b in self.sim.active() if b != self.box_id}
            rot = {b: rot.get(b, 0.0) for b in disp}
        order = {b: i for i, b in enumerate(self.sim.ids)}
        moved = tuple(sorted(mon.onset, key=lambda b: (mon.onset[b], order[b])))
        collapsed = tuple(b for b in moved if b in mon.collapse_at)
        collided = tuple(b for b in self.others if b in self.touched
                         and (disp[b] > cfg.collision_threshold or b in mon.collapse_at))
        return StepResult(self.box_id, extracted, collapsed, collided, disp, rot, moved,
                          tuple(self.frames), round(self.step * cfg.time_step, 6), self.note)


def pull(sim: PullWorld, box_id: str, seed: int, record: bool, stop_on_collapse: bool) -> StepResult:
    """Pull `box_id` out of `sim` and judge the step (see `ShelfSim.remove`)."""
    trial = PullTrial(sim, box_id, seed, record)
    extracted = trial.drive(stop_on_collapse)
    if extracted:
        sim.park(box_id)
    if not (stop_on_collapse and trial.monitor.collapse_at):
        trial.settle(stop_on_collapse, extracted)
    if record:
        trial.record_frame(not extracted)
    return trial.result(extracted)

