"""make_plan: validation, both planners, predictions on every step (fake and real physics)."""
from __future__ import annotations

import pytest

from fake_oracles import SupportGraph
from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.plan import Plan
from shelfpick.planning.planner import make_plan
from shelfpick.planning.uncertainty import Uncertainty


class FakePredictor:
    """Stands in for planning.predict.Predictor: a support graph answers the trials."""

    def __init__(self, graph: SupportGraph):
        self.graph = graph
        self.trial = graph
        self.closed = False

    def close(self):
        self.closed = True


def _box(bid, x, z, h=0.2, w=0.2, y=0.15, d=0.2, mass=1.0):
    # masses given: a known shelf then leaves only friction and the pull to draw
    return Box(bid, (w, d, h), (x, y, z), (1.0, 0.0, 0.0, 0.0), mass=mass)


# left: "bot" on the floor carrying "top"; right: "free" alone
STACK = Scene(Shelf(), (_box("bot", -0.3, 0.1), _box("top", -0.3, 0.3), _box("free", 0.3, 0.1)))
GRAPH = {"top": ["bot"]}


def test_physics_extract_removes_the_box_above_first():
    fake = FakePredictor(SupportGraph(GRAPH, ids=STACK.ids))
    plan = make_plan(STACK, "extract", "bot", predictor=fake)
    assert isinstance(plan, Plan)
    assert plan.sequence == ("top", "bot") and plan.safe
    assert [p.box for p in plan.predicted] == ["top", "bot"]
    assert plan.planner == "physics" and plan.seed == 0
    assert plan.timing["planning_s"] >= 0
    assert plan.extra["search"]["oracle_calls"] == 3
    assert not fake.closed  # a predictor handed in belongs to the caller
    Plan.from_json(plan.to_json())  # a valid document


class DoubtingPredictor(FakePredictor):
    """A predictor whose extra worlds see the last step of any plan tip a box in one of 20."""

    verified_worlds = 0

    def verify(self, sequence, extra):
        from shelfpick.planning.plan import StepPrediction
        self.verified_worlds = 10 + extra
        out = [self.graph(frozenset(sequence[:k]), b) for k, b in enumerate(sequence)]
        out[-1] = StepPrediction(out[-1].box, 1 / self.verified_worlds, 0.0, ("free",))
        return tuple(out)


def test_a_plan_the_search_calls_safe_is_safe_only_if_the_extra_worlds_agree():
    doubting = DoubtingPredictor(SupportGraph(GRAPH, ids=STACK.ids))
    plan = make_plan(STACK, "extract", "bot", predictor=doubting)
    assert plan.sequence == ("top", "bot") and not plan.safe
    assert plan.predicted[-1].collapse_prob == 1 / 40 and plan.extra["search"]["verified_worlds"] == 40
    assert plan.extra["search"]["success_prob"] == 1 - 1 / 40
    unasked = make_plan(STACK, "extract", "bot", predictor=doubting, verify=0)
    assert unasked.sequence == plan.sequence and unasked.safe and "verified_worlds" not in unasked.extra["search"]
    # a plan already unsafe is not asked again: its risk stands over the search's worlds
    risky = make_plan(STACK, "extract", "free", planner="heuristic",
                      predictor=DoubtingPredictor(SupportGraph({"free": ["bot"]}, ids=STACK.ids)))
    assert not risky.safe and "verified_worlds" not in risky.extra["search"]
    assert [p.collapse_prob for p in risky.predicted] == [0.0, 1.0, 0.0]


def test_heuristic_plan_carries_predictions_for_every_step():
    # the heuristic takes the highest first: top (0.4), then bot and free tie at 0.2 -> left first
    fake = FakePredictor(SupportGraph(GRAPH, ids=STACK.ids))
    plan = make_plan(STACK, "extract", "free", planner="heuristic", predictor=fake)
    assert plan.sequence == ("top", "bot", "free")
    assert [p.box for p in plan.predicted] == list(plan.sequence)
    assert plan.safe


def test_heuristic_plan_that_drops_a_box_is_flagged_unsafe():
    # "bot" carries "free" in this made-up graph, which the highest-first order ignores
    fake = FakePredictor(SupportGraph({"free": ["bot"]}, ids=STACK.ids))
    plan = make_plan(STACK, "clear", planner="heuristic", predictor=fake)
    assert plan.sequence == ("top", "bot", "free")
    assert not plan.safe
    assert plan.predicted[1].moved == ("free",) and plan.risk == 1.0


def test_physics_clear_visits_top_down():
    fake = FakePredictor(SupportGraph(GRAPH, ids=STACK.ids))
    plan = make_plan(STACK, "clear", predictor=fake)
    assert plan.sequence == ("top", "bot", "free") and plan.safe and plan.target is None


def test_empty_scene_clear_is_an_empty_plan():
    plan = make_plan(Scene(Shelf(), ()), "clear")
    assert plan.sequence == () and plan.safe and plan.task == "clear"


@pytest.mark.parametrize("kwargs, field", [
    ({"task": "extract", "target": "nope"}, "target"),
    ({"task": "extract"}, "target"),
    ({"task": "clear", "target": "bot"}, "target"),
    ({"task": "juggle"}, "task"),
    ({"task": "clear", "planner": "magic"}, "planner"),
    ({"task": "clear", "samples": 0}, "samples"),
    ({"task": "clear", "risk": 1.5}, "risk"),
])
def test_bad_requests_are_named(kwargs, field):
    fake = FakePredictor(SupportGraph(GRAPH, ids=STACK.ids))
    with pytest.raises(FormatError) as err:
        make_plan(STACK, predictor=fake, origin="s.json", **kwargs)
    assert f"s.json: {field}:" in str(err.value)
    assert fake.graph.asked == []  # refused before any physics


# ---------------------------------------------------------------- real physics
def test_real_physics_removes_the_box_above_the_target_first():
    plan = make_plan(STACK, "extract", "bot")
    assert plan.sequence == ("top", "bot")
    assert plan.safe and plan.risk == 0.0
    assert plan.extra["search"]["oracle_calls"] == 3  # bot (collapse), top, bot again


def test_real_physics_free_target_is_pulled_alone():
    plan = make_plan(STACK, "extract", "free")
    assert plan.sequence == ("free",) and plan.safe
    assert plan.extra["search"]["oracle_calls"] == 1


def test_real_physics_with_hidden_depths_still_unstacks():
    plan = make_plan(STACK.hide_depths(), "extract", "bot", samples=4, seed=3, model=Uncertainty.none())
    assert plan.sequence == ("top", "bot") and plan.safe


def test_real_physics_clear_and_heuristic():
    clear = make_plan(STACK, "clear")
    assert clear.sequence == ("top", "bot", "free") and clear.safe
    base = make_plan(STACK, "extract", "free", planner="heuristic")
    assert base.sequence == ("top", "bot", "free")
    assert [p.box for p in base.predicted] == ["top", "bot", "free"] and base.safe


def _bridge_scene():
    """A board bridging two boxes; depths hidden so the samples disagree."""
    return Scene(Shelf(), (
        _box("left", -0.15, 0.1), _box("right", 0.15, 0.1),
        Box("bridge", (0.5, 0.2, 0.1), (0.0, 0.15, 0.25), (1.0, 0.0, 0.0, 0.0)),
        _box("far", 0.38, 0.1))).hide_depths()


def test_same_seed_same_plan():
    scene = _bridge_scene()
    a = make_plan(scene, "extract", "left", samples=6, seed=0)
    b = make_plan(scene, "extract", "left", samples=6, seed=0)
    assert a.sequence[0] == "bridge" and a.sequence[-1] == "left"  # the board comes off first
    assert a == b  # sequence, per-step probabilities and moved boxes, safe, seed
    assert a.to_json()["predicted"] == b.to_json()["predicted"]


def _grid_scene():
    """Three columns of three 20 cm cubes, a board bridging the middle and right columns."""
    boxes = [_box(f"c{c}r{r}", x, 0.1 + 0.2 * r) for c, x in enumerate((-0.3, 0.0, 0.3)) for r in range(3)]
    boxes.append(Box("bridge", (0.5, 0.2, 0.1), (0.15, 0.15, 0.65), (1.0, 0.0, 0.0, 0.0), mass=1.0))
    return Scene(Shelf(), tuple(boxes))


def test_physics_plan_removes_far_fewer_boxes_than_the_baseline_and_holds():
    from shelfpick.planning.execute import execute_plan
    from shelfpick.planning.predict import Predictor

    scene = _grid_scene()
    with Predictor(scene) as pred:
        plan = make_plan(scene, "extract", "c1r0", predictor=pred)
        base = make_plan(scene, "extract", "c1r0", planner="heuristic", predictor=pred)
    # the board first (it rests on the column), then the column top-down
    assert plan.sequence == ("bridge", "c1r2", "c1r1", "c1r0") and plan.safe
    assert len(base.sequence) == 9  # highest first: everything but two bottom boxes
    assert execute_plan(scene, plan.sequence).ok


@pytest.mark.slow
def test_physics_plan_meets_the_exhaustive_minimum_on_the_grid():
    from shelfpick.planning.exhaustive import exhaustive_minimum
    from shelfpick.planning.predict import Predictor

    scene = _grid_scene()
    with Predictor(scene) as pred:
        for target in ("c1r0", "c2r1", "c0r0", "bridge"):
            plan = make_plan(scene, "extract", target, predictor=pred)
            best = exhaustive_minimum(scene, target)
            assert best is not None and plan.safe
            assert len(plan.sequence) == len(best), (target, plan.sequence, best)


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["structured", "unstructured"])
def test_generated_shelf_physics_plans_hold_where_a_collapse_free_order_exists(kind):
    """The issue's bar: >= 95% of the feasible tasks succeed (here all 8 targets of one shelf).

    Depths are hidden, so the planner may remove boxes the true scene did not need
    removed (one depth sample in ten that collapses makes it unstack first): the gap to
    the exhaustive minimum is measured by `shelfpick bench` over many shelves, not here.
    """
    import warnings

    from shelfpick.planning.execute import execute_plan
    from shelfpick.planning.exhaustive import min_removals, true_scene_oracle
    from shelfpick.planning.predict import Predictor
    from shelfpick.planning.shelves import generate

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        truth = generate(kind, 0, 8)
        hidden = truth.hide_depths()
        safe = true_scene_oracle(truth)
        feasible = held = 0
        try:
            with Predictor(hidden, 10, 0) as pred:
                for target in truth.ids:
                    best = min_removals(truth.ids, target, safe)
                    if best is None:
                        continue
                    feasible += 1
                    plan = make_plan(hidden, "extract", target, predictor=pred)
                    if execute_plan(truth, plan.sequence).ok:
                        held += 1
        finally:
            safe.close()
    assert feasible > 0
    assert held >= 0.95 * feasible, (held, feasible)


class _FullSampling:
    """A real Predictor without its fast path (screen, least_risky): every trial samples all."""

    def __init__(self, pred):
        self.trial = pred.trial

    def close(self):
        pass


def test_fast_path_clear_is_the_same_plan_as_full_sampling_with_fewer_pulls():
    from shelfpick.planning.clear import search_clear
    from shelfpick.planning.predict import Predictor

    scene = Scene(Shelf(), STACK.boxes + (_box("lid", 0.3, 0.3),)).hide_depths()
    order = ["bot", "free", "top", "lid"]   # the worst order: boxes carrying others come first
    depth_only = Uncertainty.none()   # the boxes' depths alone decide this little shelf's plan
    with Predictor(scene, samples=4, seed=1, model=depth_only) as fast, \
            Predictor(scene, samples=4, seed=1, model=depth_only) as full:
        a = search_clear(order, fast.trial, screen=fast.screen, least_risky=fast.least_risky)
        b = search_clear(order, full.trial)
        assert a.sequence == b.sequence and a.predicted == b.predicted and a.safe == b.safe
        assert a.sequence == ("top", "bot", "lid", "free")   # after each pull, look again from the first
        assert fast.stats["pulls"] < full.stats["pulls"]
        plan = make_plan(scene, "clear", samples=4, seed=1, predictor=fast)
        assert plan == make_plan(scene, "clear", samples=4, seed=1, predictor=_FullSampling(full))


def test_same_seed_same_plan_whichever_worker_count():
    from shelfpick.planning.predict import Predictor

    scene = _bridge_scene()
    for task, target in (("extract", "left"), ("clear", None)):
        plans = []
        for workers in (1, 2):
            with Predictor(scene, samples=4, seed=2, workers=workers) as pred:
                plans.append(make_plan(scene, task, target, samples=4, seed=2, predictor=pred))
        assert plans[0] == plans[1], task


def test_every_plan_records_what_made_it():
    """make_plan (the console's and the bench's way in, not only the CLI's) records its provenance."""
    from shelfpick.planning.plan import scene_hash

    scene = Scene(Shelf(), (Box("a", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)), Box("b", (0.2, 0.2, 0.2), (0.3, 0.1, 0.1))))
    plan = make_plan(scene, "extract", "a", "heuristic", samples=2, seed=3)
    prov = Plan.from_json(plan.to_json()).provenance
    assert prov["scene_hash"] == scene_hash(scene) and prov["shelfpick_version"]
    assert prov["samples"] == 2 and "physics" in prov
