"""Local trials: only the pulled box's neighbourhood is simulated (real PyBullet, tiny scenes)."""
from __future__ import annotations

import warnings

from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.predict import Predictor
from shelfpick.planning.sim import ShelfSim
from tests.planning.sim_scenes import cube, grid


def local_sim(scene: Scene, config: PhysicsConfig | None = None) -> ShelfSim:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return ShelfSim(scene, config, local=True)


def two_stacks() -> Scene:
    """`b` on `a` at the left, `d` on `c` at the right, 40 cm apart, and a lone `e` between."""
    return Scene(Shelf(), (cube("a", -0.35, 0.1), cube("b", -0.35, 0.3), cube("c", 0.35, 0.1),
                           cube("d", 0.35, 0.3), cube("e", 0.0, 0.1)))


def test_neighbourhood_is_the_box_its_neighbours_its_supports_and_what_stands_on_them():
    # grid(4, 3): columns b0-b2, b3-b5, b6-b8, b9-b11 (bottom to top), touching side by side
    with local_sim(grid(4, 3)) as sim:
        assert sim.neighbourhood(["b1"]) == {"b0", "b1", "b2", "b3", "b4", "b5"}
        assert sim.neighbourhood(["b11"]) == {"b6", "b7", "b8", "b9", "b10", "b11"}
    with local_sim(two_stacks()) as sim:
        assert sim.neighbourhood(["a"]) == {"a", "b"}
        assert sim.neighbourhood(["d"]) == {"c", "d"}   # its support, down to the floor


def test_local_pull_gives_the_full_verdict_and_leaves_the_far_boxes_where_they_were():
    with local_sim(two_stacks()) as sim:
        snap = sim.snapshot()
        for box in sim.scene.ids:
            sim.restore(snap)
            full = sim.remove(box, seed=3)
            sim.restore(snap)
            far = sorted(set(sim.present()) - sim.neighbourhood([box]))
            assert far, box
            before = sim.poses()
            local = sim.remove(box, seed=3, local=True)
            assert (local.extracted, local.collapsed, local.collided) == \
                (full.extracted, full.collapsed, full.collided), box
            after = sim.poses()
            for b in far:   # the position bit for bit; the quaternion's round trip through
                # Bullet may change its last bit
                assert after[b][0] == before[b][0]
                assert max(abs(x - y) for x, y in zip(after[b][1], before[b][1])) < 1e-12
            assert all(local.displacement[b] == 0.0 for b in far)
        sim.restore(snap)
        assert sim.remove("a", local=True).collapsed == ("b",)


def test_local_settle_after_a_deletion_drops_the_box_above_and_nothing_else_moves():
    with local_sim(two_stacks()) as sim:
        before = sim.poses()
        sim.delete_many(["a"], local=True)
        after = sim.poses()
        assert "b" not in after or after["b"][0][2] < before["b"][0][2] - 0.05
        for b in ("c", "d", "e"):
            assert after[b][0] == before[b][0]
            assert max(abs(x - y) for x, y in zip(after[b][1], before[b][1])) < 1e-12


def test_local_trials_are_deterministic_whatever_ran_before():
    with local_sim(grid(4, 3)) as sim:
        snap = sim.snapshot()
        first = sim.remove("b4", seed=5, local=True)
        for other in ("b0", "b10", "b7"):
            sim.restore(snap)
            sim.remove(other, seed=1, local=True)
            sim.restore(snap)
            assert sim.remove("b4", seed=5, local=True) == first


def test_a_world_without_stand_ins_and_a_recorded_pull_simulate_everything():
    with local_sim(two_stacks()) as sim:
        rec = sim.remove("e", record=True, local=True)
        assert set(rec.frames[-1][1]) >= {"a", "b", "c", "d"}   # every box is in the frames
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plain = ShelfSim(two_stacks())
    with plain:
        assert plain.remove("a", local=True).collapsed == ("b",)


def test_predictor_local_and_full_agree_on_a_tiny_shelf():
    scene = two_stacks().hide_depths()
    full_cfg = PhysicsConfig(prediction_local=False)
    with Predictor(scene, samples=3, seed=2) as local, Predictor(scene, samples=3, seed=2, config=full_cfg) as full:
        for removed, box in [((), "a"), ((), "b"), ((), "e"), (("b",), "a"), (("d",), "c")]:
            lp, fp = local.trial(frozenset(removed), box), full.trial(frozenset(removed), box)
            assert (lp.collapse_prob, lp.collision_prob, lp.moved) == \
                (fp.collapse_prob, fp.collision_prob, fp.moved), (removed, box)


def test_locality_measurement_compares_with_the_full_simulation():
    from benchmarks.sim_timing import locality

    res = locality({"grid": grid(3, 3)}, PhysicsConfig(), samples=1)
    assert res["trials"] == 9 + 8          # every pull, then every pull after taking a top box
    assert res["collapse_agree"] == 1.0
    assert 0.0 < res["kept_mean"] < 1.0
    assert res["cpu_s"]["local"] > 0 and res["steps"]["full"] > 0


def test_a_box_in_front_of_the_pulled_one_is_in_its_way_whatever_the_gap():
    # `front` stands 4 cm in front of `back` (more than the 2 cm margin), in its way out
    scene = Scene(Shelf(), (Box("back", (0.2, 0.15, 0.2), (0.0, 0.2, 0.1)),
                            Box("front", (0.1, 0.08, 0.1), (0.0, 0.045, 0.05)),
                            cube("far", 0.35, 0.1)))
    with local_sim(scene) as sim:
        assert sim.neighbourhood(["back"]) == {"back"}
        assert sim.neighbourhood(["back"], corridor=True) == {"back", "front"}
        snap = sim.snapshot()
        full = sim.remove("back", seed=1)
        sim.restore(snap)
        local = sim.remove("back", seed=1, local=True)
        assert "front" in full.collided
        assert (local.extracted, local.collapsed, local.collided) == \
            (full.extracted, full.collapsed, full.collided)


def test_a_leaning_box_on_a_leaning_support_moves_with_it():
    """Bounding boxes of tilted boxes interpenetrate in z: the box on top is still 'on' its support,
    so a trial never leaves it frozen on a box that moves (a static box there pins the pile)."""
    from shelfpick.planning.locality import neighbourhood
    # p (pulled) props up `lean` (tilted: its AABB reaches down past p's top); `top` rests on `lean`
    # with its AABB bottom 5 cm below lean's AABB top (more than the 3 cm allowed for tilt)
    box = {
        "p": ((-0.46, 0.0, 0.50), (-0.23, 0.25, 0.81)),
        "lean": ((-0.26, 0.0, 0.67), (0.02, 0.25, 1.02)),
        "top": ((-0.25, 0.0, 0.97), (-0.03, 0.2, 1.20)),
        "far": ((0.30, 0.0, 0.0), (0.50, 0.2, 0.2)),
    }
    keep = neighbourhood(box, ["p"], margin=0.02, overlap=0.005, tilt=0.03, corridor=True)
    assert keep == {"p", "lean", "top"}
