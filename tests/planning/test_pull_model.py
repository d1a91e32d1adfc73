"""The pull's model artefacts found under issue 32, each on a tiny scene.

- A drive that holds the box's height rigidly shares the top box's weight with the box below (0.4
  weights on it) until the lower box tips into it, then presses it down with up to 10 weights:
  `hold_spring` (off by default: it did not make the gate better on our bench) bounds it.
- A box that tips 20 deg or moves 5 cm and comes back is a collapse at that moment:
  `peak_tipping` (off by default, for the same reason) judges it at the end of the step.
- A box resting on a few mm of a neighbour's top edge is thrown off the shelf when that
  neighbour is lifted: `edge_perch` (off by default) moves it off the edge first.
- Two drives tried against the judge's engine on our shelves (session 47), off by default:
  `pull_turn` holds the box's centre and lets it turn; `hold_carry` (with `hold_spring`) carries a
  dragged box's weight, as the drive carries a lifted one.

Each test fails with its setting off (the rigid hold: 0.42 and 9.6 weights; the peak rule: a
collapse at 25 deg; no perch repair: the box thrown 1.14 m).
"""
from __future__ import annotations

import math
import warnings

from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.pull import CollapseMonitor
from shelfpick.planning.sim import ShelfSim

CARTON = (0.23, 0.31, 0.25)


def _sim(boxes: tuple[Box, ...], cfg: PhysicsConfig) -> ShelfSim:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ShelfSim(Scene(Shelf(width=1.0, depth=0.35, height=1.0), boxes), cfg)


def _held_drag(top: float, low: float, friction: float, carry: float = 0.0) -> list[float]:
    """The normal force (in the top box's weights) on the box below at every step of dragging the top
    box off it, the drive holding its height (and with `carry` its weight)."""
    cfg = PhysicsConfig(lateral_friction=friction, pull_force=172.0, pull_force_weights=1e6,
                        pull_lift=0.0, pull_hold=True, hold_spring=True, hold_carry=carry)
    sim = _sim((Box("low", CARTON, (0.0, 0.16, 0.125), mass=low),
                Box("top", CARTON, (0.0, 0.16, 0.375), mass=top)), cfg)
    p, tb, lb = sim.client, sim.body("top"), sim.body("low")
    forces: list[float] = []
    step = sim.step

    def watched() -> None:
        step()
        forces.append(sum(c[9] for c in p.getContactPoints(bodyA=tb, bodyB=lb)) / (top * cfg.gravity))

    sim.step = watched   # type: ignore[method-assign]
    try:
        sim.remove("top", seed=1, stop_on_collapse=False)
    finally:
        sim.close()
    return forces


def test_a_held_height_leaves_the_weight_on_the_box_below_and_never_presses_it_down_hard():
    # a quiet drag: the box below carries the top box (the rigid hold carried 60 % of it)
    quiet = [f for f in _held_drag(1.12, 1.0, 0.65) if f > 0]
    assert sum(quiet) / len(quiet) > 0.9
    # a heavy box on a light one, high friction: the rigid hold pressed with 9.6 weights (90th
    # percentile); the bounded spring adds at most half a weight and the vibration's tenth
    wedge = sorted(_held_drag(2.0, 0.34, 0.88))
    assert wedge[int(0.9 * len(wedge))] < 1.6


def test_hold_carry_takes_a_dragged_boxs_weight_off_the_box_below():
    # off by default: on our shelves it cleared 220 of 240 draws our worlds failed and the judge's
    # engine held, and missed 240 more that the engine failed (docs/results/risk-gate.md, session 47)
    carried = _held_drag(1.12, 1.0, 0.65, carry=1.0)
    assert sum(carried) / len(carried) < 0.3


def _monitor_one_box() -> tuple[ShelfSim, CollapseMonitor, int]:
    sim = _sim((Box("b", CARTON, (0.0, 0.16, 0.125), mass=1.0),), PhysicsConfig(peak_tipping=True))
    return sim, CollapseMonitor(sim, ["b"]), sim.body("b")


def _tilt(sim: ShelfSim, body: int, degrees: float) -> None:
    """Turn the box about its front bottom edge (what a drag off its top does to it)."""
    a = math.radians(degrees)
    hy, hz = CARTON[1] / 2, CARTON[2] / 2
    edge = (0.16 - hy, 0.0)
    y = edge[0] + hy * math.cos(a) - hz * math.sin(a)
    z = edge[1] + hy * math.sin(a) + hz * math.cos(a)
    sim.client.resetBasePositionAndOrientation(body, [0.0, y, z], [math.sin(a / 2), 0.0, 0.0, math.cos(a / 2)])


def test_a_box_that_tips_and_falls_back_is_not_a_collapse_but_one_past_its_tipping_angle_is():
    sim, mon, body = _monitor_one_box()
    start = sim.client.getBasePositionAndOrientation(body)
    try:
        _tilt(sim, body, 25.0)          # 25 deg, its centre ~6 cm away: it can still fall back
        mon.look(1)
        sim.client.resetBasePositionAndOrientation(body, *start)
        mon.look(2)
        mon.judge_end(3)
        assert mon.collapse_at == {}
        _tilt(sim, body, 55.0)          # past atan(11.5 / 12.5) = 43 deg: it falls on
        mon.look(4)
        assert "b" in mon.collapse_at
    finally:
        sim.close()


def test_a_box_slid_level_past_the_peak_is_a_collapse_at_once():
    sim, mon, body = _monitor_one_box()
    try:
        pos, orn = sim.client.getBasePositionAndOrientation(body)
        sim.client.resetBasePositionAndOrientation(body, [pos[0], pos[1] - 0.06, pos[2]], orn)
        mon.look(1)
        assert mon.collapse_at == {"b": 1}
    finally:
        sim.close()


def test_a_box_on_a_few_mm_of_a_lifted_neighbours_edge_is_moved_off_it_and_stays():
    cfg = PhysicsConfig(lateral_friction=0.76, pull_force=132.0, pull_force_weights=1e6, edge_perch=0.005)
    # `top` stands on `left` and reaches 1 mm over `right`'s top edge (face error); `right` is
    # lifted 6 mm and pulled. Before: `top` was thrown 1.1 m off the shelf
    sim = _sim((Box("left", CARTON, (-0.116, 0.16, 0.125), mass=1.04),
                Box("right", CARTON, (0.116, 0.16, 0.125), mass=2.57),
                Box("top", CARTON, (-0.113, 0.16, 0.375), mass=2.58)), cfg)
    try:
        assert any("'top'" in r and "off the edge of 'right'" in r for r in sim.repairs)
        r = sim.remove("right", seed=1)
        assert r.extracted and r.collapsed == ()
        assert r.displacement["top"] < 0.005
    finally:
        sim.close()


def _drive_joints(cfg: PhysicsConfig) -> list[tuple]:
    """(joint type, the box's pivot, where the world holds it) of each constraint the pull makes."""
    sim = _sim((Box("low", CARTON, (0.0, 0.16, 0.125), mass=1.0),
                Box("top", CARTON, (0.0, 0.16, 0.375), mass=1.0)), cfg)
    made: list[tuple] = []
    create = sim.client.createConstraint

    def watched(*args, **kw):
        made.append((args[4], tuple(args[6]), tuple(args[7])))
        return create(*args, **kw)

    sim.client.createConstraint = watched   # type: ignore[method-assign]
    try:
        assert sim.remove("top", seed=1).extracted
        return made
    finally:
        sim.close()


def test_pull_turn_holds_the_centre_and_leaves_the_orientation_free():
    import pybullet

    drag = dict(pull_lift=0.0, pull_hold=True)
    (kind, pivot, at), = _drive_joints(PhysicsConfig(**drag))
    assert kind == pybullet.JOINT_FIXED and pivot == (0.0, -CARTON[1] / 2, 0.0)
    (kind, pivot, at), = _drive_joints(PhysicsConfig(**drag, pull_turn=True))
    assert kind == pybullet.JOINT_POINT2POINT and pivot == (0.0, 0.0, 0.0)
    assert abs(at[1] - 0.16) < 0.01 and abs(at[2] - 0.375) < 0.01   # the box's centre, where it stood
    # a box dragged with its height free is not held, whatever the setting
    (kind, _, _), = _drive_joints(PhysicsConfig(pull_lift=0.0, pull_hold=False, pull_turn=True))
    assert kind == pybullet.JOINT_PRISMATIC
