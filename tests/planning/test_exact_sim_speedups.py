"""Speed-ups of the simulation that must not change a single number (docs/speed.md, issue 32).

A world's kept start state (`ShelfSim.start_state`, saved while building) stands in for a new
snapshot: the test runs both ways side by side and asks for bit-identical worlds and StepResults.
"""
from __future__ import annotations

import warnings

import pytest

from shelfpick.planning.sim import ShelfSim

from tests.planning.sim_scenes import column, grid, stacked, twelve


def _state(sim: ShelfSim) -> tuple:
    p = sim.client
    return (sim.sim_time, tuple((p.getBasePositionAndOrientation(sim.body(b)), p.getBaseVelocity(sim.body(b)))
                                for b in sim.ids))


_SCENES = {"stacked": stacked, "column": column, "grid": grid, "twelve": twelve}


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
