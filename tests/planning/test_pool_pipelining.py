"""A Predictor's workers answer several messages in flight (issue 32's speed): the pipelined
path must give what one process gives, build the same worlds, and hand clean pipes on (real physics)."""
from __future__ import annotations

from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.predict import Predictor
from shelfpick.planning.worker_pool import WorkerPool
from tests.planning.sim_scenes import column, cube


def _floating() -> Scene:
    """`high` hangs 20 cm above `a`: it drops in every draw, so it never stands as seen."""
    return Scene(Shelf(), (cube("a", 0.0, 0.1), cube("high", 0.0, 0.5), cube("c", 0.4, 0.1))).hide_depths()


def test_a_shelf_that_does_not_stand_gets_the_worlds_one_process_builds():
    # `high` never stands: every sample tries every attempt, in whichever worker builds it
    scene = _floating()
    with Predictor(scene, samples=4, seed=3) as serial, Predictor(scene, samples=4, seed=3, workers=2) as pool:
        assert serial.scene_check["samples_not_standing"] > 0          # the case this test is about
        assert pool.sample_scenes == serial.sample_scenes
        assert pool.scene_check == serial.scene_check                  # same redraws, same attempts
        for call in [(frozenset(), "a"), (frozenset(), "c"), (frozenset({"high"}), "a")]:
            assert pool.trial(*call) == serial.trial(*call)
        assert pool.plan_results(["high", "a"], 6) == serial.plan_results(["high", "a"], 6)


def test_interleaved_questions_previews_and_more_worlds_answer_as_one_process():
    scene = column(4).hide_depths()
    with WorkerPool(2) as workers, Predictor(scene, samples=4, seed=2) as serial, \
            Predictor(scene, samples=4, seed=2, workers=2, pool=workers) as pool:
        # an unsafe screen stops at sample 0 while sample 1 is still on its way
        assert pool.screen(frozenset(), "c1") == serial.screen(frozenset(), "c1")
        assert (pool.stats["pulls"], serial.stats["pulls"]) == (2, 1)
        assert pool.screen(frozenset(), "f") == serial.screen(frozenset(), "f")
        frames = [s.to_json(frames=True) for s in pool.preview(["c3", "c2"], sample=1)]
        assert frames == [s.to_json(frames=True) for s in serial.preview(["c3", "c2"], sample=1)]
        assert pool.trial(frozenset(), "c1") == serial.trial(frozenset(), "c1")
        # the gate's way: every step at once, in worlds built in the same message stream
        assert pool.plan_results(["c3", "c2", "c1"], 7) == serial.plan_results(["c3", "c2", "c1"], 7)
        assert pool.stats["pulls"] == serial.stats["pulls"]   # the sample run ahead was used, none wasted


def test_a_reply_nobody_waited_for_does_not_reach_the_next_predictor():
    with WorkerPool(2) as workers:
        with Predictor(column(4).hide_depths(), samples=4, seed=2, workers=2, pool=workers) as first:
            first.screen(frozenset(), "c1")               # stops at sample 0; sample 1 ran ahead
            assert any(first._outbox.pending(w) for w, _ in first._workers)
        # the same processes serve the next Predictor (another shelf): its first reply is its own
        scene = Scene(Shelf(), (Box("x", (0.2, 0.2, 0.2), (0.1, 0.12, 0.1)), cube("y", 0.1, 0.3)))
        with Predictor(scene.hide_depths(), samples=3, seed=5, workers=2, pool=workers) as second, \
                Predictor(scene.hide_depths(), samples=3, seed=5) as serial:
            assert second.sample_scenes == serial.sample_scenes
            assert second.trial(frozenset(), "x") == serial.trial(frozenset(), "x")



def test_a_dead_end_compared_on_risk_intervals_plans_as_the_full_predictions_do():
    # a generated 11-box shelf whose target `b0` cannot come out safely: the search compares
    # blocker plans at its dead ends. Sampled only as far as each comparison needs, the plan and
    # every prediction in it are those of the search that completes every compared pull
    from shelfpick.planning.extract import search_extract
    from shelfpick.planning.shelves import generate

    scene = generate("unstructured", 918273325, 11).hide_depths()
    out = []
    for lazy in (False, True):
        with Predictor(scene, samples=4, seed=918273325) as p:
            kw = {"bounds": p.risk_interval, "more": p.sample_more} if lazy else {}
            res = search_extract(scene.ids, "b0", p.trial, screen=lambda r, b: p.screen(r, b, 0.0), **kw)
            out.append((res.sequence, res.predicted, res.safe, p.stats["pulls"]))
    (seq, predicted, safe, pulls), (lazy_seq, lazy_predicted, lazy_safe, lazy_pulls) = out
    assert not safe and len(seq) > 2                       # a dead end with blockers, the case at hand
    assert (lazy_seq, lazy_predicted, lazy_safe) == (seq, predicted, safe)
    assert lazy_pulls < pulls                              # and it did sample less
