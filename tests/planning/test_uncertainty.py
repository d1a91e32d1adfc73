"""Draws of what the camera cannot know: pure, seeded, inside their ranges."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.uncertainty import depth_ranges, sample_depths
from shelfpick.planning.uncertainty import Uncertainty, draw_config, draw_scene
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


def _face(w: float, h: float, y_front: float = 0.0) -> Box:
    """A box seen only by its front face (w x h) at `y_front`, depth unknown (10 cm placeholder)."""
    return Box("f", (w, 0.10, h), (0.0, y_front + 0.05, h / 2), depth_known=False)


def test_a_face_of_a_stock_type_has_that_types_depth():
    from shelfpick.planning.uncertainty import type_depths

    types = Uncertainty().catalogue
    assert type_depths(_face(0.23, 0.25), types, 0.025, 0.30) == (0.31,)
    assert type_depths(_face(0.31, 0.24), types, 0.025, 0.30) == (0.23, 0.25)  # 31x25 or 31x23: either
    assert type_depths(_face(0.31, 0.255), types, 0.01, 0.30) == (0.23,)
    assert type_depths(_face(0.20, 0.21), types, 0.025, 0.30) == (0.2,)
    assert type_depths(_face(0.50, 0.17), types, 0.025, 0.30) == (0.17,)
    assert type_depths(_face(0.40, 0.40), types, 0.025, 0.30) == ()        # no type: the shelf decides
    assert type_depths(_face(0.23, 0.25), types, 0.025, 0.20) == ()        # 31 cm deep cannot fit there
    assert type_depths(_face(0.17, 0.17), types, 0.025, 0.30) == ()        # the long box end-on: 50 cm deep


def test_draws_take_the_type_depth_and_the_shelf_range_without_a_catalogue():
    scene = Scene(Shelf(), (_face(0.23, 0.25), _face(0.40, 0.40, 0.0).__class__(
        "g", (0.40, 0.10, 0.40), (0.3, 0.05, 0.2), depth_known=False)))
    ranges = depth_ranges(scene)
    with_types, without = Uncertainty(face_error=0.0), Uncertainty(face_error=0.0, catalogue=())
    typed = [draw_scene(scene, 0, k, with_types, ranges) for k in range(20)]
    plain = [draw_scene(scene, 0, k, without, ranges) for k in range(20)]
    assert all(abs(s.box("f").size[1] - 0.31) <= 0.01 + 1e-9 or s.box("f").size[1] == ranges["f"][1]
               for s in typed)
    assert max(s.box("f").size[1] for s in plain) - min(s.box("f").size[1] for s in plain) > 0.05
    # a face no type explains is drawn from the shelf, the same stream with or without types
    assert [s.box("g").size[1] for s in typed] == [s.box("g").size[1] for s in plain]
    # the front face never moves: the box grows backwards
    assert all(s.box("f").front_center == scene.box("f").front_center for s in typed)
    # a redraw that reaches less deep looks for another explanation than the type
    shallow = draw_scene(scene, 0, 0, with_types, ranges, reach=0.0)
    assert shallow.box("f").size[1] == pytest.approx(ranges["f"][0])


def test_half_trust_draws_the_type_in_about_half_the_worlds():
    scene = Scene(Shelf(), (_face(0.23, 0.25, -0.02),))    # 2 cm proud: 31 cm deep fits
    ranges = depth_ranges(scene)
    model = Uncertainty(face_error=0.0, catalogue_trust=0.5, catalogue_depth_error=0.0)
    typed = sum(draw_scene(scene, 3, k, model, ranges).box("f").size[1] == pytest.approx(0.31)
                for k in range(200))
    assert 70 <= typed <= 130


def test_face_size_and_depth_errors_stay_in_range_and_leave_the_other_draws_alone():
    scene = _hidden()
    ranges = depth_ranges(scene)
    base = Uncertainty()
    model = replace(base, face_size_error=0.005, face_depth_error=0.004)
    moved_depth = moved_size = 0
    for k in range(10):
        plain, drawn = draw_scene(scene, 3, k, base, ranges), draw_scene(scene, 3, k, model, ranges)
        for p, b in zip(plain.boxes, drawn.boxes):
            # the same depth and mass draws; only the face's size and its place along its normal
            assert b.size[1] == p.size[1] and b.mass == p.mass
            dw, dh = b.size[0] - p.size[0], b.size[2] - p.size[2]
            assert max(abs(dw), abs(dh)) <= 0.005 + 1e-9
            d = [b.front_center[i] - p.front_center[i] for i in range(3)]
            assert abs(d[0]) < 1e-9 and abs(d[2]) < 1e-9 and abs(d[1]) <= 0.004 + 1e-9
            moved_size += max(abs(dw), abs(dh)) > 1e-4
            moved_depth += abs(d[1]) > 1e-4
    assert moved_size > 50 and moved_depth > 50


def test_a_known_shelf_draws_no_face_error():
    model = Uncertainty(face_size_error=0.01, face_depth_error=0.01).without_face_error()
    assert (model.face_error, model.face_size_error, model.face_depth_error) == (0.0, 0.0, 0.0)
    assert model.mass == Uncertainty().mass
