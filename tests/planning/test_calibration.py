"""The calibrated plan risk (issue 32): the Wilson interval, the fitted map, the gate that asks more
worlds only while it cannot decide, and what `make_plan` records."""
from __future__ import annotations

import math
import random

import pytest

from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Scene, Shelf
from shelfpick.planning.calibration import DEFAULT_MAX_PLAN_RISK, Calibration, fit, plan_failures, wilson
from shelfpick.planning.gate import gate
from shelfpick.planning.plan import Plan, StepPrediction
from shelfpick.planning.planner import make_plan
from shelfpick.planning.step_result import StepResult
from tests.planning.sim_scenes import cube, stacked


def test_the_wilson_interval_holds_the_share_and_narrows_with_more_worlds():
    for k, n in [(0, 10), (1, 10), (5, 10), (10, 10), (3, 40)]:
        lo, hi = wilson(k, n, 1.2816)
        assert 0.0 <= lo <= k / n <= hi <= 1.0
    assert wilson(0, 40, 1.2816)[1] < wilson(0, 20, 1.2816)[1] < wilson(0, 10, 1.2816)[1]
    assert wilson(0, 10, 1.2816)[1] == pytest.approx(1.2816 ** 2 / (10 + 1.2816 ** 2))


def test_the_calibrated_chance_rises_with_the_failing_worlds_and_sits_in_its_interval():
    cal = Calibration(intercept=-2.0, slope=1.0, not_standing=1.5)
    probs = [cal.probability(k, 20) for k in range(21)]
    assert probs == sorted(probs) and probs[0] < probs[-1]
    for k in (0, 3, 20):
        lo, hi = cal.interval(k, 20)
        assert lo <= cal.probability(k, 20) <= hi
    assert cal.probability(2, 20, stands=False) > cal.probability(2, 20)   # a shelf not as seen is riskier
    # more worlds with none failing: the interval's upper end comes down, so a plan can be decided
    assert cal.interval(0, 40)[1] < cal.interval(0, 10)[1]


def test_below_the_benchs_floor_more_failing_worlds_still_mean_a_higher_chance():
    """The shipped lifting map puts 0, 1 and 2 failing worlds of 20 far below what its bench cannot
    rule out (`minimum`); clamped there they were one chance, so the plans with failing worlds were
    not told from the plans without any (docs/results/risk-gate.md, "What the floor hides")."""
    from shelfpick.planning.calibration import LIFT
    # the upper ends that decide "safe", as the clamped map gave them: the verdicts do not move
    before = {10: [0.028, 0.028, 0.0573, 0.1737], 20: [0.028, 0.028, 0.028, 0.028]}
    for n in (10, 20):
        probs = [round(LIFT.probability(k, n), 4) for k in range(4)]
        assert probs[0] >= LIFT.minimum and probs == sorted(set(probs)), probs
        for k in range(4):
            lo, hi = LIFT.interval(k, n)
            assert round(hi, 4) == before[n][k] and lo <= LIFT.probability(k, n) <= hi


def test_decided_means_the_interval_is_wholly_on_one_side():
    cal = Calibration(intercept=-2.0, slope=1.0)
    t = 0.05
    for k, n in [(0, 10), (0, 40), (1, 20), (10, 10)]:
        lo, hi = cal.interval(k, n)
        assert cal.decided(k, n, t) == (hi < t or lo >= t)


def test_the_fit_recovers_a_known_map_from_seeded_draws():
    true = Calibration(intercept=-1.5, slope=0.8, not_standing=1.0)
    rng = random.Random(3)
    rows = []
    for _ in range(6000):
        n = rng.choice((10, 20, 30))
        k = rng.randint(0, n)
        st = rng.random() < 0.7
        rows.append((k, n, st, rng.random() < true.probability(k, n, st)))
    got = fit(rows)
    assert got.intercept == pytest.approx(-1.5, abs=0.2) and got.slope == pytest.approx(0.8, abs=0.1)
    assert got.not_standing == pytest.approx(1.0, abs=0.25)
    with pytest.raises(ValueError):
        fit([])


def test_the_fits_floor_counts_every_plan_it_would_call_safe_not_only_those_no_world_failed():
    # a bench like ours with a lifting truth: 12 plans no world failed, 150 that failed in 1-4 of 30
    # worlds, none of them failed on the truth; the rest failed in most worlds and on the truth.
    # Counted over the 12 alone, the floor's upper end (0.12) shut the gate on every plan
    rows = [(0, 30, True, False)] * 12 + [(k, 30, True, False) for k in (1, 2, 3, 4) for _ in range(38)]
    rows += [(k, 30, True, True) for k in range(20, 31) for _ in range(10)]
    got = fit(rows)
    assert got.minimum_high < DEFAULT_MAX_PLAN_RISK
    assert got.interval(1, 30)[1] < DEFAULT_MAX_PLAN_RISK
    # a bench whose low-share plans do fail keeps a floor that says so
    risky = fit([(k, 30, True, k % 4 == 0) for k in range(0, 5) for _ in range(40)]
                + [(k, 30, True, True) for k in range(20, 31) for _ in range(10)])
    assert risky.minimum_high > DEFAULT_MAX_PLAN_RISK


def test_the_fits_floor_counts_a_plan_once_however_many_prefixes_of_its_worlds_it_gives():
    # 40 quiet plans that held, each seen at 10, 20 and 30 worlds: 120 rows but 40 verdicts
    quiet = [(0, n, True, False) for _ in range(40) for n in (10, 20, 30)]
    risky = [(k, 30, True, True) for k in range(20, 31) for _ in range(10)]
    groups = [i // 3 for i in range(len(quiet))] + [1000 + i for i in range(len(risky))]
    once = fit(quiet + risky, groups=groups)
    thrice = fit(quiet + risky)
    assert once.minimum == pytest.approx(0.5 / 41) and thrice.minimum == pytest.approx(0.5 / 121)
    assert once.minimum_high > thrice.minimum_high
    assert (once.intercept, once.slope) == (thrice.intercept, thrice.slope)


def test_a_plan_fails_in_a_world_when_any_of_its_steps_does():
    assert plan_failures([[True, False, False], [False, False, True]]) == (2, 3)
    assert plan_failures([[False] * 5]) == (0, 5)
    assert plan_failures([]) == (0, 0)


def test_calibration_json_round_trips_and_refuses_a_wrong_field():
    cal = Calibration(intercept=-1.0, slope=0.5, fitted_on="test")
    assert Calibration.from_json(cal.to_json()) == cal
    with pytest.raises(FormatError, match="calibration.slope"):
        Calibration.from_json({"slope": "steep"})


class ScriptedWorlds:
    """A predictor whose world i fails the plan's last step when i is in `failing` (any number of
    worlds: the gate may ask for more); it counts the worlds it was asked of."""

    def __init__(self, failing: set[int], drawn: bool = True):
        self.failing, self.drawn, self.asked = failing, drawn, []

    def plan_results(self, sequence, total):
        n = total if self.drawn else 1
        self.asked.append(n)
        ok = [StepResult(b, True) for b in sequence[:-1]]
        last = sequence[-1]
        return [[ok[j]] * n for j in range(len(ok))] + [
            [StepResult(last, True, collapsed=("x",)) if i in self.failing else StepResult(last, True)
             for i in range(n)]]

    def aggregate(self, box, results):
        return StepPrediction(box, sum(bool(r.collapsed) for r in results) / len(results))


CAL = Calibration(intercept=-3.5, slope=0.4)


def test_the_gate_asks_few_worlds_of_a_clear_plan_and_more_of_a_borderline_one():
    clear_fail = ScriptedWorlds(set(range(10)))           # every world fails: decided at once
    g = gate(clear_fail, ("a", "b"), True, CAL, 0.05, first=10, max_worlds=40)
    assert clear_fail.asked == [10] and not g.safe and g.failed == 10
    quiet = ScriptedWorlds(set())
    g = gate(quiet, ("a", "b"), True, CAL, 0.05, first=10, max_worlds=40)
    assert g.safe and g.failed == 0
    assert quiet.asked[-1] == g.worlds and quiet.asked == sorted(quiet.asked)
    # the gate stops as soon as the interval no longer straddles the threshold
    assert all(not CAL.decided(0, n, 0.05) for n in quiet.asked[:-1])
    assert CAL.decided(0, g.worlds, 0.05) or g.worlds == 40
    borderline = ScriptedWorlds({3})
    g2 = gate(borderline, ("a", "b"), True, CAL, 0.05, first=10, max_worlds=40)
    assert len(borderline.asked) >= len(quiet.asked)
    assert g2.probability > g.probability and g2.predicted[-1].collapse_prob == pytest.approx(1 / g2.worlds)
    # the same worlds, the same verdict: the gate is a function of its inputs
    again = gate(ScriptedWorlds({3}), ("a", "b"), True, CAL, 0.05, first=10, max_worlds=40)
    assert again == g2


def test_the_gate_does_not_loop_on_a_shelf_with_one_world():
    one = ScriptedWorlds(set(), drawn=False)
    g = gate(one, ("a",), True, CAL, 0.05, first=1, max_worlds=40)
    assert one.asked == [1] and g.worlds == 1


def test_the_gate_asks_the_worlds_after_the_searchs_own():
    """The search chose the plan in its first worlds; the gate counts only the worlds after them."""
    picked = ScriptedWorlds(set(range(10, 20)))           # held in the search's 10, fails in every later one
    g = gate(picked, ("a", "b"), True, CAL, 0.05, first=10, max_worlds=40, skip=10)
    assert picked.asked == [20] and g.worlds == 10 and g.failed == 10 and not g.safe
    lucky = gate(ScriptedWorlds(set(range(10, 20))), ("a", "b"), True, CAL, 0.05, first=10, max_worlds=40)
    assert lucky.failed == 0 and lucky.safe                # the search's own worlds: the winner's curse
    one = ScriptedWorlds(set(), drawn=False)               # nothing drawn: its one world is asked
    g1 = gate(one, ("a",), True, CAL, 0.05, first=1, max_worlds=40, skip=1)
    assert g1.worlds == 1 and one.asked[-1] == 1


def test_make_plan_gates_on_worlds_the_search_never_saw(monkeypatch):
    scene = Scene(Shelf(), (cube("a", 0.0, 0.1), cube("c", 0.4, 0.1))).hide_depths()
    from shelfpick.planning.predict import Predictor

    asked = []
    real = Predictor.plan_results

    def spy(self, sequence, total):
        asked.append(total)
        return real(self, sequence, total)

    monkeypatch.setattr(Predictor, "plan_results", spy)
    plan = make_plan(scene, "extract", "a", samples=4, verify=8)
    assert asked and asked[0] == 4 + 4                    # the search's 4 worlds, then 4 more to ask
    assert plan.extra["search"]["plan_risk"]["worlds"] == asked[-1] - 4


def test_a_plan_is_safe_when_the_upper_end_of_its_calibrated_risk_is_below_the_threshold():
    """Real physics: a cube on the floor with nothing on it, pulled out; the plan records the
    threshold and the interval, and a threshold below the interval's upper end makes it unsafe."""
    scene = Scene(Shelf(), (cube("a", 0.0, 0.1), cube("c", 0.4, 0.1))).hide_depths()
    plan = make_plan(scene, "extract", "a", samples=4, verify=8)
    g = plan.extra["search"]["plan_risk"]
    assert plan.extra["search"]["max_plan_risk"] == DEFAULT_MAX_PLAN_RISK
    assert g["failed_worlds"] == 0 and g["low"] <= g["probability"] <= g["high"]
    assert plan.safe == (g["high"] < DEFAULT_MAX_PLAN_RISK)
    assert plan.extra["search"]["success_prob"] == pytest.approx(1 - g["probability"], abs=1e-4)
    strict = make_plan(scene, "extract", "a", samples=4, verify=8, max_plan_risk=1e-4)
    assert not strict.safe and strict.extra["search"]["plan_risk"]["max_plan_risk"] == 1e-4
    assert Plan.from_json(strict.to_json()).extra["search"]["max_plan_risk"] == 1e-4
    # pulling the bottom of a stack drops the box on it in every world: decided at once, unsafe
    from shelfpick.planning.predict import Predictor

    with Predictor(stacked().hide_depths(), samples=4) as pred:
        under = gate(pred, ("a",), True, Calibration(0.0, 1.0), 0.5, first=4, max_worlds=12)
    assert under.failed == under.worlds == 4 and not under.safe and under.low >= 0.5


@pytest.mark.parametrize("bad", [0.0, -0.1, 1.5, math.nan, True])
def test_a_wrong_plan_threshold_is_refused_naming_it(bad):
    scene = Scene(Shelf(), (cube("a", 0.0, 0.1),))
    with pytest.raises(FormatError, match="max_plan_risk"):
        make_plan(scene, "extract", "a", max_plan_risk=bad)


def test_the_map_follows_how_the_cells_gripper_pulls():
    from shelfpick.planning.calibration import DRAG, LIFT, calibration_for
    from shelfpick.planning.uncertainty import Uncertainty

    assert calibration_for(Uncertainty().pull_modes) is LIFT          # lift or drag: it lifts where it can
    assert calibration_for(()) is LIFT                                # nothing drawn: the planner's own pull lifts
    assert calibration_for(("drag",)) is DRAG and calibration_for(("ride", "drag")) is DRAG
    # against a truth that drags at a held height 4.5 % of our bench's quiet plans failed: its upper
    # end keeps every plan of a drag-only cell above 5 %, but its chances are no longer 43 %
    assert DRAG.interval(0, 40)[1] > DEFAULT_MAX_PLAN_RISK > LIFT.interval(0, 10)[1]
    assert DRAG.probability(0, 40) < 0.05 < DRAG.probability(4, 10)
    assert "held height" in DRAG.fitted_on
