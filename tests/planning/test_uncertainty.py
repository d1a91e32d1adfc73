"""Draws of what the camera cannot know: pure, seeded, inside their ranges."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from perception.scene import Box, Scene, Shelf
from planning.physics import PhysicsConfig
from planning.uncertainty import depth_ranges, sample_depths
from planning.uncertainty import Uncertainty, draw_config, draw_scene
from tests.planning.sim_scenes import twelve


def _hidden() -> Scene:
    return twelve().hide_depths()


def test_same_seed_and_draw_same_world_other_draw_other_world():
    scene, model = _hidden(), Uncertainty()
    ranges = depth_ranges(scene)
    assert draw_scene(scene, 4, 2, model, ranges) == draw_scene(scene, 4, 2, model, ranges)
    assert draw_scene(scene, 4, 2, model, ranges) != draw_scene(scene, 4, 3, model, ranges)
    assert draw_scene(scene, 4, 2, model, ranges) != draw_scene(scene, 5, 2, model, ranges)
    cfg = PhysicsConfig()
    assert draw_config(cfg, 4, 2, model) == draw_config(cfg, 4, 2, model)


def test_every_drawn_quantity_stays_in_its_range():
    scene, model = _hidden(), Uncertainty()
    ranges = depth_ranges(scene)
    masses, frictions, modes = [], [], set()
    for k in range(40):
        drawn = draw_scene(scene, 0, k, model, ranges)
        for seen, b in zip(scene.boxes, drawn.boxes):
            lo, hi = ranges[b.id]
            assert lo - 1e-9 <= b.size[1] <= hi + 1e-9
            assert model.mass[0] <= b.mass <= model.mass[1]
            masses.append(b.mass)
            # the face moved in its own plane by at most the face error, never in depth
            d = [b.front_center[i] - seen.front_center[i] for i in range(3)]
            assert abs(d[1]) < 1e-9 and max(abs(d[0]), abs(d[2])) <= model.face_error + 1e-9
        cfg = draw_config(PhysicsConfig(), 0, k, model)
        assert model.friction[0] <= cfg.lateral_friction <= model.friction[1]
        assert model.pull_speed[0] <= cfg.pull_speed <= model.pull_speed[1]
        assert model.pull_force[0] <= cfg.pull_force <= model.pull_force[1]
        frictions.append(cfg.lateral_friction)
        modes.add((cfg.pull_lift > 0, cfg.pull_hold))
    assert modes == {(True, True), (False, True)}          # lift, and drag with the height held
    assert min(masses) < 0.6 and max(masses) > 3.0           # log-uniform reaches both ends
    assert len({round(f, 6) for f in frictions}) == 40


def test_known_masses_and_depths_are_kept():
    box = Box("k", (0.2, 0.2, 0.2), (0.0, 0.12, 0.1), mass=2.5)
    scene = Scene(Shelf(), (box,))
    drawn = draw_scene(scene, 0, 0, replace(Uncertainty(), face_error=0.0), {})
    assert drawn.box("k").mass == 2.5 and drawn.box("k").size == box.size


def test_no_uncertainty_but_depth_is_the_methods_depth_sample():
    scene = _hidden()
    ranges = depth_ranges(scene)
    for k in range(3):
        assert draw_scene(scene, 7, k, Uncertainty.none(), ranges) == sample_depths(scene, 7, k, ranges=ranges)
    assert draw_config(PhysicsConfig(), 7, 0, Uncertainty.none()) == PhysicsConfig()


def test_an_unknown_pull_mode_is_refused():
    with pytest.raises(ValueError, match="pull mode 'yank'"):
        draw_config(PhysicsConfig(), 0, 0, replace(Uncertainty(), pull_modes=("yank",)))
    assert math.isfinite(draw_config(PhysicsConfig(), 0, 0, Uncertainty()).pull_force)
