"""Predictor: depth samples, aggregation, caching and determinism (real physics)."""
from __future__ import annotations

import pytest

from shelfpick.perception.scene import Box, Scene, Shelf, yaw_quat
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.predict import Predictor
from shelfpick.planning.uncertainty import Uncertainty, depth_range, depth_ranges, sample_depths
from tests.planning.sim_scenes import column, stacked, twelve


def test_depth_samples_keep_the_front_face_and_stay_inside_the_back_wall():
    base = twelve()
    turned = Box("t", (0.2, 0.2, 0.2), (0.38, 0.1, 0.7), yaw_quat(0.2))
    scene = base.with_boxes(base.boxes + (turned,)).hide_depths()
    depth = scene.shelf.depth
    lows = []
    for i in range(20):
        s = sample_depths(scene, seed=3, sample=i)
        for orig, new in zip(scene.boxes, s.boxes):
            assert new.front_center == pytest.approx(orig.front_center, abs=1e-9)
            assert max(c[1] for c in new.corners()) <= depth + 1e-9
            lo, hi = depth_range(scene, orig)
            assert lo - 1e-9 <= new.size[1] <= hi + 1e-9
            lows.append(new.size[1])
    assert min(lows) >= min(PhysicsConfig().min_sample_depth, 0.15) - 1e-9
    assert len({round(d, 6) for d in lows}) > 100  # really drawn, not fixed


def test_hidden_depth_never_passes_through_a_box_behind():
    scene = Scene(Shelf(), (Box("front", (0.2, 0.1, 0.2), (0.0, 0.05, 0.1), depth_known=False),
                            Box("behind", (0.2, 0.1, 0.2), (0.0, 0.25, 0.1))))
    for i in range(10):
        s = sample_depths(scene, 0, i)
        assert max(c[1] for c in s.box("front").corners()) <= 0.2 + 1e-9


def test_a_box_stacked_on_a_slightly_tilted_one_does_not_cap_its_depth():
    """Judge scene s07: the box above sits 1 cm further back and both lean 2.4 deg, so their
    faces overlap by a few mm in z. That is no box behind this one: the depth range must still
    reach the back wall (it was capped at 1 cm, and every sample held a 1 cm deep box)."""
    import math
    lean = (math.cos(0.021), 0.0, -math.sin(0.021), 0.0)
    lower = Box("lower", (0.31, 0.10, 0.23), (-0.26, 0.068, 0.426), lean, depth_known=False)
    upper = Box("upper", (0.31, 0.10, 0.23), (-0.34, 0.079, 0.653), lean, depth_known=False)
    scene = Scene(Shelf(), (lower, upper))
    lo, hi = depth_range(scene, lower)
    assert lo == pytest.approx(PhysicsConfig().min_sample_depth)
    assert hi > 0.25


def test_same_seed_same_samples_other_seed_other_samples():
    scene = twelve().hide_depths()
    assert sample_depths(scene, 1, 0) == sample_depths(scene, 1, 0)
    assert sample_depths(scene, 1, 0) != sample_depths(scene, 2, 0)


def test_depth_ranges_computed_once_give_the_same_samples():
    scene = twelve().hide_depths()
    ranges = depth_ranges(scene)
    assert set(ranges) == set(scene.ids)
    for i in range(3):
        assert sample_depths(scene, 4, i, ranges=ranges) == sample_depths(scene, 4, i)


def test_top_box_collapse_is_predicted_and_named_first():
    with Predictor(stacked().hide_depths(), samples=4, seed=0) as pred:
        assert pred.worlds == 4
        under = pred.trial(frozenset(), "a")
        assert under.collapse_prob == 1.0 and under.moved[0] == "b"
        free = pred.trial(frozenset(), "c")
        assert free.collapse_prob == 0.0 and free.moved == ()
        after = pred.trial(frozenset({"b"}), "a")
        assert after.collapse_prob == 0.0 and after.collision_prob == 0.0
        assert pred.trial(frozenset(), "a") is under  # cached
        assert pred.stats["cache_hits"] == 1


def test_known_shelf_still_draws_friction_masses_and_pull():
    # the scene file gives the geometry, not the masses, friction or pull: those are still drawn
    with Predictor(stacked(), samples=4) as pred:
        assert pred.worlds == 4
        cfgs = {(round(s.config.lateral_friction, 3), s.config.pull_lift) for s in pred._local.sims.values()}
        assert len(cfgs) > 1
        masses = {tuple(b.mass for b in s.scene.boxes) for s in pred._local.sims.values()}
        assert len(masses) == 4 and all(m is not None for ms in masses for m in ms)
        # the geometry is the scene's own in every world
        assert all(s.scene.boxes[i].size == b.size for s in pred._local.sims.values() for i, b in enumerate(stacked().boxes))


def test_known_depths_and_nothing_else_to_draw_use_one_world():
    with Predictor(stacked(), samples=10, model=Uncertainty.none()) as pred:
        assert pred.worlds == 1
        assert pred.trial(frozenset(), "a").collapse_prob == 1.0
        # with known depths the wide, heavy-enough lower box does not tip when the top one slides off
        assert pred.trial(frozenset(), "b").collapse_prob == 0.0


def test_same_seed_same_predictions_whatever_the_call_order():
    scene = column(5).hide_depths()
    calls = [(frozenset(), "c4"), (frozenset(), "c2"), (frozenset({"c4"}), "c3"), (frozenset(), "f")]
    with Predictor(scene, samples=3, seed=5) as p1, Predictor(scene, samples=3, seed=5) as p2:
        a = [p1.trial(r, b) for r, b in calls]
        b = [p2.trial(r, b) for r, b in reversed(calls)][::-1]
        assert a == b
        assert [x.to_json() for x in p1.results(*calls[2])] == [x.to_json() for x in p2.results(*calls[2])]
    assert a[1].collapse_prob == 1.0 and "c3" in a[1].moved   # the column above falls
    assert a[3].collapse_prob == 0.0


def test_early_stop_stops_sampling_an_unsafe_candidate():
    with Predictor(stacked().hide_depths(), samples=5, early_stop_risk=0.0) as pred:
        p = pred.trial(frozenset(), "a")
        assert p.collapse_prob > 0.0 and p.moved[0] == "b"
        assert pred.stats["pulls"] == 1
        assert pred.trial(frozenset(), "c").collapse_prob == 0.0
        assert pred.stats["pulls"] == 6


def test_preview_records_frames_and_leaves_the_world_as_it_was():
    with Predictor(stacked().hide_depths(), samples=2) as pred:
        before = pred.trial(frozenset(), "a")
        steps = pred.preview(["b", "a"], sample=1)
        assert [s.box for s in steps] == ["b", "a"] and all(s.ok for s in steps)
        assert all(len(s.frames) >= 3 for s in steps)
        pred._cache.clear()
        assert pred.trial(frozenset(), "a") == before


def test_bad_calls():
    with Predictor(stacked(), samples=1) as pred:
        with pytest.raises(Exception, match="'zz'"):
            pred.trial(frozenset(), "zz")
        with pytest.raises(ValueError):
            pred.trial(frozenset({"a"}), "a")
    with pytest.raises(ValueError):
        Predictor(stacked(), samples=0)


def test_process_pool_gives_the_same_predictions_as_one_process():
    scene = stacked().hide_depths()
    calls = [(frozenset(), "a"), (frozenset(), "c"), (frozenset({"b"}), "a")]
    with Predictor(scene, samples=3, seed=4) as serial, Predictor(scene, samples=3, seed=4, workers=2) as pool:
        assert pool.worlds == 3 and pool.sims == [] and pool.stats["workers"] == 2
        assert [serial.trial(*c) for c in calls] == [pool.trial(*c) for c in calls]
        assert [r.to_json() for r in serial.results(*calls[0])] == [r.to_json() for r in pool.results(*calls[0])]
        a, b = serial.preview(["b", "a"], sample=1), pool.preview(["b", "a"], sample=1)
        assert [s.to_json(frames=True) for s in a] == [s.to_json(frames=True) for s in b]


def test_screen_stops_at_the_first_collapsing_sample_and_least_risky_is_exact():
    scene = column(4).hide_depths()
    with Predictor(scene, samples=4, seed=2) as lazy, Predictor(scene, samples=4, seed=2) as full:
        s = lazy.screen(frozenset(), "c1")          # two boxes stand on c1: every sample collapses
        assert s.risk == 0.25 and s.moved[0] == "c2" and lazy.stats["pulls"] == 1
        safe = lazy.screen(frozenset(), "f")        # a free box: all samples run, the answer is exact
        assert safe == full.trial(frozenset(), "f") and lazy.stats["pulls"] == 5
        boxes = ["c0", "c1", "c3", "f"]
        exact = {b: full.trial(frozenset(), b).risk for b in boxes}
        best = min(boxes, key=lambda b: (exact[b], boxes.index(b)))
        assert lazy.least_risky(frozenset(), boxes) == best
        assert lazy.trial(frozenset(), "c1") == full.trial(frozenset(), "c1")  # completes the prefix


def test_pool_screens_the_same_prefix_as_one_process():
    scene = column(4).hide_depths()
    with Predictor(scene, samples=3, seed=1) as serial, Predictor(scene, samples=3, seed=1, workers=2) as pool:
        for b in ("c1", "c3", "f"):
            assert serial.screen(frozenset(), b) == pool.screen(frozenset(), b)
        assert serial.least_risky(frozenset(), ["c0", "c2", "c3"]) == pool.least_risky(frozenset(), ["c0", "c2", "c3"])


def test_pool_workers_outlive_a_predictor_and_serve_the_next_one():
    from shelfpick.planning.worker_pool import WorkerPool

    scene = stacked().hide_depths()
    with WorkerPool(2) as pool:
        with Predictor(scene, samples=2, seed=1, workers=2, pool=pool) as first:
            a = first.trial(frozenset(), "a")
            pids = pool.pids()
        assert len(pids) == 2 and pool.pids() == pids
        with Predictor(scene, samples=2, seed=1, workers=2, pool=pool) as second, \
                Predictor(scene, samples=2, seed=1) as serial:
            assert pool.pids() == pids      # the same processes
            assert second.trial(frozenset(), "a") == a == serial.trial(frozenset(), "a")
    assert all(not _alive(pid) for pid in pids)     # the owner closed the pool: no process left


def test_a_predictor_without_a_pool_stops_its_workers():
    from shelfpick.planning import worker_pool

    with Predictor(stacked().hide_depths(), samples=2, seed=1, workers=2) as pred:
        pids = pred._pool.pids()
    assert len(pids) == 2 and all(not _alive(pid) for pid in pids)
    with pytest.raises(ValueError, match="never forks"):
        worker_pool.WorkerPool(2, method="fork")


def _alive(pid: int) -> bool:
    import os
    import time

    for _ in range(50):
        try:
            os.kill(pid, 0)
            with open(f"/proc/{pid}/stat") as f:
                if f.read().split(")")[-1].split()[0] == "Z":
                    return False
        except (ProcessLookupError, FileNotFoundError):
            return False
        time.sleep(0.1)
    return True


def test_turned_box_whose_deep_samples_hit_a_neighbour_still_gets_samples():
    """A box turned in the plane swings its back corners sideways as its sampled depth
    grows; redraws reach less deep instead of refusing the perceived scene."""
    from dataclasses import replace

    from shelfpick.perception.scene import Box, Scene, Shelf, quat_to_matrix, yaw_quat
    from shelfpick.planning.predict import Predictor

    q = yaw_quat(-0.6)
    r = quat_to_matrix(q)
    front, d = (-0.19, 0.0, 0.1), 0.05
    turned = replace(Box("b1", (0.2, d, 0.2), (0, 0, 0), q, depth_known=False),
                     position=tuple(front[i] + r[i][1] * d / 2 for i in range(3)))
    neighbour = Box("b0", (0.2, 0.05, 0.2), (0.0, 0.045, 0.1), depth_known=False)
    p = Predictor(Scene(Shelf(), (neighbour, turned)), samples=4, seed=0)
    try:
        pred = p.trial(frozenset(), "b0")
        assert pred.collapse_prob == 0.0
    finally:
        p.close()


def _steps(pred, sequence):
    out, removed = [], frozenset()
    for b in sequence:
        out.append(pred.trial(removed, b))
        removed = removed | {b}
    return out


@pytest.mark.parametrize("workers", [1, 2])
def test_verify_asks_the_worlds_a_larger_predictor_has_and_leaves_the_search_alone(workers):
    scene = column(3).hide_depths()
    seq = ["c2", "c1"]
    with Predictor(scene, samples=3, seed=6, workers=workers) as pred, Predictor(scene, samples=5, seed=6) as big:
        before = _steps(pred, seq)
        verified = pred.verify(seq, 2)
        assert list(verified) == _steps(big, seq)           # the same 5 worlds, whoever built them
        assert pred.verified_worlds == 5 and pred.worlds == 3
        pred._cache.clear()
        assert _steps(pred, seq) == before                   # trials still answer over the first 3
        assert pred.risk_bound(frozenset(), "c2") == (0.0, True)
        assert pred.verify(seq, 2) == verified               # built once, kept
    assert all(p.risk == 0.0 for p in verified)


def test_verify_counts_a_collapse_in_every_world_it_asks():
    # pulling the bottom of a column tips it in every world, the extra ones as well
    scene = column(3).hide_depths()
    with Predictor(scene, samples=1, seed=0) as pred:
        first = pred.trial(frozenset(), "c0")
        v = pred.verify(["c0"], 3)
        assert first.collapse_prob == 1.0 and v[0].collapse_prob == 1.0 and pred.verified_worlds == 4


def test_verify_has_nothing_more_to_ask_of_a_known_shelf_with_nothing_drawn():
    with Predictor(stacked(), samples=10, model=Uncertainty.none()) as pred:
        v = pred.verify(["b", "a"], 10)
        assert pred.verified_worlds == 1 and [p.risk for p in v] == [0.0, 0.0]
