"""benchmarks/gate_mass_ceiling.py: masses drawn again leave the geometry alone, the summary counts
both sides, argument errors exit 2, and one real plan judged by the independent judge."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from bench_scripts import JUDGE, load

gm = load("gate_mass_ceiling")
TRUTH = {"shelf": {}, "boxes": [{"id": "a", "size": [0.2, 0.2, 0.2], "position": [0, 0.1, 0.1],
                                 "orientation": [1, 0, 0, 0], "mass": 1.0},
                                {"id": "b", "size": [0.2, 0.2, 0.2], "position": [0, 0.1, 0.3],
                                 "orientation": [1, 0, 0, 0], "mass": 2.0}]}


def test_redrawn_masses_are_seeded_in_range_and_change_nothing_else():
    one, again = gm.redraw_masses(TRUTH, 0, 3, (0.5, 3.0)), gm.redraw_masses(TRUTH, 0, 3, (0.5, 3.0))
    assert one == again and one != gm.redraw_masses(TRUTH, 0, 4, (0.5, 3.0))
    for new, old in zip(one["boxes"], TRUTH["boxes"]):
        assert 0.5 <= new["mass"] <= 3.0
        assert {k: v for k, v in new.items() if k != "mass"} == {k: v for k, v in old.items() if k != "mass"}


def _row(ok: bool, safe: bool, fails: int) -> dict:
    return {"ok": ok, "declared_safe": safe, "fails": fails, "draws": 20}


def test_the_summary_counts_plans_safe_on_their_geometry_on_both_sides():
    rows = [_row(True, True, 0), _row(True, True, 8), _row(True, False, 1), _row(False, True, 20)]
    s = gm.summary(rows, 0.05)
    assert (s["held"], s["held_low_risk"], s["held_no_failing_draw"]) == (3, 2, 1)
    assert s["held_surely_low_risk"] == 0          # 20 draws cannot show a chance surely under 5 %
    assert s["declared_safe"] == 3 and s["declared_safe_failing_in_a_fifth_or_more"] == 2
    assert s["low_risk_failed_on_judge"] == 0


def test_expected_sides_let_an_oracle_average_a_risky_plan_in_with_quiet_ones():
    """Two plans that never fail and one failing in 2 of 20 draws: the oracle may call all three
    safe (mean 1/30 <= 5 %), not a fourth failing in 10 of 20; the plans at the lowest risk, two
    quiet ones and the half-failing one, fail in 1/6 of the draws."""
    rows = [_row(True, True, 0), _row(True, True, 0), _row(True, False, 2), _row(False, True, 10)]
    e = gm.expected_sides(rows, 0.05)
    assert e["oracle_safe"] == 3 and e["oracle_collapse_share"] == round(0.1 / 3, 3)
    assert e["expected_holding"] == 3.4 and e["oracle_held_safe_share"] == round(2.9 / 3.4, 3)
    assert e["oracle_largest_share"] == 0.1 and e["ours_held_safe_share"] == round(2.5 / 3.4, 3)
    lowest = [dict(r, risk=x) for r, x in zip(rows, (0.01, 0.01, 0.2, 0.01))]
    assert (gm.expected_sides(lowest, 0.05)["floor_plans"], gm.expected_sides(lowest, 0.05)["floor_mean_share"]) \
        == (3, round(0.5 / 3, 3))
    assert gm.expected_sides(rows[3:], 0.05)["oracle_safe"] == 0


def test_bad_arguments_exit_2(capsys, tmp_path: Path) -> None:
    assert gm.main(["--rows", str(tmp_path / "missing.jsonl")]) == 2
    assert "cannot read judge rows" in capsys.readouterr().err
    assert gm.main(["--rows", "x", "--draws", "0"]) == 2
    assert "--draws" in capsys.readouterr().err
    assert gm.main([]) == 2


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_a_free_box_holds_under_every_mass_draw(tmp_path: Path, capsys) -> None:
    rows = tmp_path / "rows.jsonl"
    rows.write_text(json.dumps({"scene": "s00", "target": "b5", "ok": True, "declared_safe": True,
                                "risk": 0.01, "sequence": ["b5"]}) + "\n")
    out = tmp_path / "ceiling.jsonl"
    assert gm.main(["--rows", str(rows), "--judge", str(JUDGE), "--draws", "2", "--out", str(out)]) == 0
    got = [json.loads(line) for line in out.read_text().splitlines()]
    assert [(r["scene"], r["fails"], r["draws"]) for r in got] == [("s00", 0, 2)]
    assert '"held_no_failing_draw": 1' in capsys.readouterr().out


def test_the_noise_floor_ranks_by_share_and_a_calibrated_risk_still_errs_by_chance():
    rows = [_row(True, True, 0)] * 30 + [_row(False, False, 20)] * 10 + [_row(i % 2 == 0, False, 10) for i in range(20)]
    f = gm.noise_floor(rows, reps=200)
    assert f["ideal_auc"] > 0.8                    # every sure failure outranks every quiet plan
    med, p5, p95 = f["calibrated_error_by_chance"]
    assert 0 <= p5 <= med <= p95 < 0.3 and med > 0  # the coin-flip plans leave an error no risk can avoid
    assert f == gm.noise_floor(rows, reps=200)      # seeded
    sure = [_row(True, True, 0)] * 30 + [_row(False, False, 20)] * 10
    assert gm.noise_floor(sure, reps=50)["calibrated_error_by_chance"] == [0.0, 0.0, 0.0]


def test_another_run_of_the_same_plans_is_scored_on_the_same_draws(tmp_path: Path):
    ceiling = [{"scene": "s00", "target": "b1", "sequence": ["b1"], "ok": True, "declared_safe": True,
                "risk": 0.01, "fails": 0, "draws": 20},
               {"scene": "s00", "target": "b2", "sequence": ["b3", "b2"], "ok": True, "declared_safe": True,
                "risk": 0.01, "fails": 8, "draws": 20}]
    later = tmp_path / "rows.jsonl"
    later.write_text(json.dumps({"scene": "s00", "target": "b1", "sequence": ["b1"], "ok": True,
                                 "declared_safe": True, "risk": 0.01}) + "\n" +
                     json.dumps({"scene": "s00", "target": "b2", "sequence": ["b3", "b2"], "ok": True,
                                 "declared_safe": False, "risk": 0.3}) + "\n")
    got = gm.regate(ceiling, str(later))
    assert [r["declared_safe"] for r in got] == [True, False] and [r["fails"] for r in got] == [0, 8]
    assert gm.gate_auc(got, 0.05) == 1.0
    later.write_text(json.dumps({"scene": "s00", "target": "b1", "sequence": ["b2", "b1"], "ok": True,
                                 "declared_safe": True, "risk": 0.01}) + "\n")
    with pytest.raises(gm.UsageError, match="planned differently"):
        gm.regate(ceiling, str(later))


def test_expected_auc_weighs_each_pair_by_the_chance_that_one_collapses_and_the_other_holds():
    # a plan that always fails above one that never does: 1; the same risk: a tie, 0.5; reversed: 0
    assert gm.expected_auc([0.9, 0.1], [1.0, 0.0]) == 1.0
    assert gm.expected_auc([0.5, 0.5], [1.0, 0.0]) == 0.5
    assert gm.expected_auc([0.1, 0.9], [1.0, 0.0]) == 0.0
    # two plans that never fail: no pair to score
    assert gm.expected_auc([0.1, 0.2], [0.0, 0.0]) != gm.expected_auc([0.1, 0.2], [0.0, 0.0])
    # shares 0.5 and 0: the pair counts with weight 0.5 * 1 one way, 0 * 0.5 the other
    assert gm.expected_auc([0.2, 0.1], [0.5, 0.0]) == 1.0


def test_plans_of_keeps_the_rows_own_verdicts_for_the_plans_another_run_reached(tmp_path: Path):
    ceiling = [{"scene": "s00", "target": t, "sequence": [t], "ok": True, "declared_safe": True, "risk": 0.01,
                "fails": 0, "draws": 20} for t in ("b0", "b1", "b2")]
    other = tmp_path / "partial.jsonl"
    other.write_text(json.dumps({"scene": "s00", "target": "b1", "sequence": ["b1"], "ok": False,
                                 "declared_safe": False, "risk": 0.3}) + "\n")
    kept = gm.regate(ceiling, str(other), verdicts=False)
    assert kept == [ceiling[1]]
    assert gm.regate(ceiling, str(other))[0]["declared_safe"] is False
