"""Speed-ups of the simulation that must not change a single number (docs/speed.md, issue 32).

Each test runs the code as it was (the reference, copied here) beside the code as it is, and asks
for bit-identical worlds and StepResults: a settle that stopped one step earlier or later, or a
verdict read at another step, fails them.
"""
from __future__ import annotations

import math
import warnings

import pytest

from shelfpick.planning.geometry3 import dist, norm, rot_angle_deg
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.pull import CollapseMonitor
from shelfpick.planning.sim import ShelfSim

from tests.planning.sim_scenes import column, grid, stacked, twelve


class _ReferenceSettle(ShelfSim):
    """ShelfSim with `_settle` as it was: one `_moving(first=True)` call after each step."""

    def _settle(self, max_time: float) -> bool:
        cfg = self.config
        need = max(1, int(round(cfg.rest_window / cfg.time_step)))
        calm = 0
        for _ in range(int(math.ceil(max_time / cfg.time_step))):
            self.step()
            calm = calm + 1 if not self._moving(first=True) else 0
            if calm >= need:
                return True
        return False


def _reference_look(self: CollapseMonitor, step: int) -> bool:
    """`CollapseMonitor.look` as it was, with geometry3's helpers."""
    p, cfg = self.p, self.cfg
    pose, velocity = p.getBasePositionAndOrientation, p.getBaseVelocity
    moving = False
    for k, ob in enumerate(self.bodies):
        bid = self.others[k]
        lin, ang = velocity(ob)
        v, w = norm(lin), norm(ang)
        if v > cfg.rest_velocity or w > cfg.rest_angular_velocity:
            moving = True
        if bid in self.collapse_at:
            continue
        pos, orn = pose(ob)
        d = dist(pos, self.start[k][0])
        if bid not in self.onset and (d > cfg.onset_displacement or v > cfg.onset_velocity):
            self.onset[bid] = step
        if self._certain(k, d, rot_angle_deg(orn, self.start[k][1]), v, w):
            self.collapse_at[bid] = step
            self.onset.setdefault(bid, step)
    return moving


def _state(sim: ShelfSim) -> tuple:
    p = sim.client
    return (sim.sim_time, tuple((p.getBasePositionAndOrientation(sim.body(b)), p.getBaseVelocity(sim.body(b)))
                                for b in sim.ids))


_SCENES = {"stacked": stacked, "column": column, "grid": grid, "twelve": twelve}
# a wobbly column (low friction, loose rest thresholds) makes the settles stop at other steps
_CONFIGS = [PhysicsConfig(), PhysicsConfig(lateral_friction=0.3, rest_velocity=0.05, rest_window=0.05)]


@pytest.mark.parametrize("name", sorted(_SCENES))
@pytest.mark.parametrize("cfg", _CONFIGS)
def test_settle_stops_at_the_same_step_as_the_reference(name, cfg):
    """Build (settle, knock), a take-away settled whole and one settled locally: the same state."""
    scene = _SCENES[name]()
    ids = scene.ids
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sims = [cls(scene, cfg, local=True) for cls in (ShelfSim, _ReferenceSettle)]
    try:
        assert _state(sims[0]) == _state(sims[1])
        assert sims[0].settle_moves == sims[1].settle_moves
        assert sims[0].nudge(0.5) == sims[1].nudge(0.5)
        for sim in sims:
            sim.delete(ids[0])
        assert _state(sims[0]) == _state(sims[1])
        for sim in sims:
            sim.delete_many(ids[1:3], local=True)   # frozen boxes: not looked at by either
        assert _state(sims[0]) == _state(sims[1])
    finally:
        for sim in sims:
            sim.close()


@pytest.mark.parametrize("name", sorted(_SCENES))
def test_pull_verdicts_are_the_reference_ones(name, monkeypatch):
    """Every box pulled, with and without stopping at the first collapse, locally and not: the
    StepResults (verdict, collapse order, displacements, sim time) equal the reference look's."""
    scene = _SCENES[name]()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ShelfSim(scene, local=True)
    try:
        snap = sim.snapshot()
        got = {}
        for look in (CollapseMonitor.look, _reference_look):
            monkeypatch.setattr(CollapseMonitor, "look", look)
            out = []
            for b in scene.ids:
                for stop, local in ((False, False), (True, True)):
                    sim.restore(snap)
                    out.append(sim.remove(b, seed=7, stop_on_collapse=stop, local=local))
            got[look] = out
        new, ref = got.values()
        assert new == ref
        assert any(r.collapsed for r in ref) and any(r.ok for r in ref)   # both kinds of verdict
    finally:
        sim.close()


@pytest.mark.parametrize("name", sorted(_SCENES))
def test_the_kept_start_state_gives_the_same_knock_and_trials_as_a_new_snapshot(name):
    """A fresh world's knock and first trial state restore `start_state` (saved while building)
    instead of a snapshot taken after the build: the same knock, the same pulls after it."""
    scene = _SCENES[name]()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        old, new = ShelfSim(scene, local=True), ShelfSim(scene, local=True)
    try:
        assert old.nudge(0.5) == new.nudge(0.5, now=new.start_state)   # as it was / as it is
        snaps = {old: old.snapshot(), new: new.start_state}
        assert _state(old) == _state(new)
        for b in scene.ids:
            results = []
            for sim in (old, new):
                sim.restore(snaps[sim])
                results.append(sim.remove(b, seed=3, local=True))
            assert results[0] == results[1]
            for sim in (old, new):          # and a take-away's settle from the start state
                sim.restore(snaps[sim])
                sim.delete_many([b], local=True)
            assert _state(old) == _state(new)
    finally:
        old.close()
        new.close()
