"""Taking an unsafe plan's blockers top first, against fake oracles on a tiny column."""
from __future__ import annotations

from fake_oracles import STILL, risky, table_oracle
from perception.scene import Box, Scene, Shelf
from planning.extract import SearchResult
from planning.reorder import reorder_extraction, top_first

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
