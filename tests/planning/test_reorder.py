"""Taking an unsafe plan's blockers top first, against fake oracles on a tiny column."""
from __future__ import annotations

import math

import pytest
from fake_oracles import STILL, risky, table_oracle
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.extract import SearchResult
from shelfpick.planning.reorder import leaning, reorder_extraction, top_first
from shelfpick.planning.resolution import prefer, resolution

# a column: t at the bottom, m on t, h on m (tops 0.2, 0.4, 0.6 m)
COLUMN = Scene(Shelf(), tuple(Box(i, (0.2, 0.2, 0.2), (0.0, 0.15, z)) for i, z in
                              (("t", 0.1), ("m", 0.3), ("h", 0.5))))


def _pull_under_load(removed, box):
    """Pulling m while h still rests on it drags h (risk 0.5); h first is quiet; t is
    always a little risky, so no plan is safe."""
    if box == "m" and "h" not in removed:
        return risky(0.5, "h")
    if box == "t":
        return risky(0.1, "x")
    return STILL


def _plan(oracle, seq):
    removed, preds = frozenset(), []
    for b in seq:
        preds.append(oracle(removed, b))
        removed = removed | {b}
    return SearchResult(tuple(seq), tuple(preds), False)


def test_top_first_keeps_the_target_last():
    assert top_first(COLUMN, ("m", "h", "t")) == ("h", "m", "t")


def test_blockers_pulled_from_under_a_load_are_taken_top_first():
    oracle = table_oracle(_pull_under_load)
    out = reorder_extraction(_plan(oracle, ("m", "h", "t")), COLUMN, oracle)
    assert out.sequence == ("h", "m", "t")
    assert [p.risk for p in out.predicted] == [0.0, 0.0, 0.1] and not out.safe


def test_a_safe_plan_or_a_no_better_order_is_left_alone():
    oracle = table_oracle(lambda removed, box: STILL)
    safe = _plan(oracle, ("m", "h", "t"))
    assert reorder_extraction(safe, COLUMN, oracle) is safe
    # the other order is no better (the target's risk dominates either way): the search's order stays
    flat = table_oracle(lambda removed, box: risky(0.1, "x") if box == "t" else STILL)
    plan = _plan(flat, ("m", "h", "t"))
    assert reorder_extraction(plan, COLUMN, flat) is plan


def _column_oracle(m_under_load: float, h_first: float):
    """m pulled with h still on it risks `m_under_load`; h pulled with m still under it risks
    `h_first` (so top first can be predicted a little worse); the target is never quiet."""
    def answer(removed, box):
        if box == "m" and "h" not in removed and m_under_load:
            return risky(m_under_load, "h")
        if box == "h" and "m" not in removed and h_first:
            return risky(h_first, "m")
        if box == "t":
            return risky(0.1, "x")
        return STILL
    return table_oracle(answer)


def test_resolution_is_one_standard_error_of_the_worlds():
    assert resolution(0.9, 10) == pytest.approx(math.sqrt(0.9 * 0.1 / 10))
    assert resolution(0.9, None) == 0.0 and resolution(0.9, 1) == 0.0
    assert resolution(1.0, 10) == 0.0 and resolution(0.0, 10) == 0.0


def test_top_first_is_kept_when_the_worlds_cannot_tell_the_orders_apart():
    # the search's order: 0.95 * 0.9; top first: 0.9 * 0.9, worse by 0.045, within one
    # standard error of ten worlds (0.085 at 0.855), so top first wins
    oracle = _column_oracle(0.05, 0.1)
    plan = _plan(oracle, ("m", "h", "t"))
    out = reorder_extraction(plan, COLUMN, oracle, worlds=10)
    assert out.sequence == ("h", "m", "t")
    assert out.success_prob == pytest.approx(0.81)
    # without the worlds' count nothing says the difference is noise: the better-predicted order stays
    assert reorder_extraction(plan, COLUMN, oracle) is plan


def test_top_first_predicted_clearly_worse_is_not_taken():
    # top first 0.6 * 0.9 against 0.95 * 0.9: worse by far more than the resolution
    oracle = _column_oracle(0.05, 0.4)
    plan = _plan(oracle, ("m", "h", "t"))
    assert reorder_extraction(plan, COLUMN, oracle, worlds=10) is plan


def test_prefer_takes_the_persons_order_within_the_slack_only():
    oracle = _column_oracle(0.05, 0.1)
    search = _plan(oracle, ("m", "h", "t"))
    person = _plan(oracle, ("h", "m", "t"))
    assert prefer(person, search, 0.05) is person
    assert prefer(person, search, 0.04) is search
    assert prefer(None, search, 0.5) is search
    assert prefer(person, search, 0.0) is search           # no slack: only a better order
    assert prefer(search, person, 0.0) is search


def test_on_a_leaning_box_the_highest_top_gets_no_benefit_of_the_doubt():
    # the same column with h leaning 12 deg: its top is the highest, but it leans on the others;
    # top first, within the worlds' resolution, is not taken (only an order predicted better would be)
    lean = (math.cos(math.radians(6)), math.sin(math.radians(6)), 0.0, 0.0)
    tilted = Scene(Shelf(), tuple(b if b.id != "h" else Box("h", b.size, b.position, lean)
                                  for b in COLUMN.boxes))
    assert leaning(tilted, ("m", "h")) and not leaning(tilted, ("m", "t"))
    oracle = _column_oracle(0.05, 0.1)
    plan = _plan(oracle, ("m", "h", "t"))
    assert reorder_extraction(plan, tilted, oracle, worlds=10) is plan
    assert reorder_extraction(plan, COLUMN, oracle, worlds=10).sequence == ("h", "m", "t")
