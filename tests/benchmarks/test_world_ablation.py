"""benchmarks/world_ablation.py: the conditions widen one unknown at a time from the pinned model, the
summary averages over the plans the reference holds, bad arguments exit 2, and one real plan on one of
our own shelves asked of the judge's engine and of our worlds."""
from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest
from bench_scripts import JUDGE, load

wa = load("world_ablation")


def test_each_condition_widens_one_unknown_of_the_pinned_model():
    from shelfpick.planning.uncertainty import Uncertainty

    c = wa.conditions((0.5, 3.0))
    pinned, hide = c["pinned physics, our masses"]
    assert not hide and pinned["pull_modes"] == ("drag",) and pinned["friction"] == (0.75, 0.75)
    assert c["+ friction 0.6-0.9"][0] == {**pinned, "friction": Uncertainty().friction}
    assert c["+ depths hidden"] == (pinned, True)
    assert c["default cell (all of them)"] == ({}, True)


def _row(ref: list[bool], pinned: list, cond: list[bool], safe: bool = True) -> dict:
    return {"shelf": "structured-1", "target": "b1", "sequence": ["b1"], "draws": len(ref), "declared_safe": safe,
            "reference": {"pybullet": ref}, "pinned": pinned, "conditions": {"x": cond}}


def test_the_summary_averages_over_quiet_plans_and_skips_worlds_never_built():
    rows = [_row([False] * 4, [False, True, None, False], [True, False, False, False]),
            _row([True, True, False, False], [True, True, False, False], [])]
    s = {r["condition"]: r for r in wa.summary(rows)}
    assert s["reference (pybullet)"]["quiet"] == 0.0 and s["reference (pybullet)"]["all"] == 0.25
    pinned = s["pinned (same masses as the reference)"]
    assert pinned["quiet"] == pytest.approx(1 / 3, abs=1e-3)     # the draw with no world is left out
    assert pinned["agreement"] == pytest.approx(6 / 7, abs=1e-3)
    assert s["x"]["quiet"] == 0.25 and s["x"]["all"] == 0.25 and s["x"]["no_world"] == 1


def test_bad_arguments_exit_2(capsys, tmp_path: Path):
    assert wa.main(["--seeds", "x", "--out", str(tmp_path / "o")]) == 2
    assert "--seeds" in capsys.readouterr().err
    assert wa.main(["--draws", "0", "--out", str(tmp_path / "o")]) == 2


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_one_plan_of_our_own_shelf_against_the_judges_engine(tmp_path: Path, capsys):
    if str(JUDGE) not in sys.path:
        sys.path.insert(0, str(JUDGE))
    out = tmp_path / "rows.jsonl"
    argv = ["--kinds", "structured", "--seeds", "41000-41000", "--targets", "1", "--draws", "2",
            "--judge", str(JUDGE), "--out", str(out)]
    assert wa.main(argv) == 0
    (row,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert row["shelf"] == "structured-41000" and row["sequence"][-1] == row["target"]
    assert len(row["reference"]["pybullet"]) == 2 and len(row["pinned"]) == 2
    assert set(row["conditions"]) == set(wa.conditions((0.5, 3.0)))
    assert all(len(v) in (0, 2) for v in row["conditions"].values())
    assert "| default cell (all of them) |" in capsys.readouterr().out


def test_contact_friction_gives_each_body_the_square_root():
    c = wa.contact_conditions((0.5, 3.0))
    ov, hide = c["pinned, contact friction 0.75"]
    assert not hide and ov["friction"][0] ** 2 == pytest.approx(0.75)
    lo, hi = c["+ contact friction 0.6-0.9"][0]["friction"]
    assert (lo * lo, hi * hi) == (pytest.approx(0.6), pytest.approx(0.9))


def test_gate_windows_read_the_search_worlds_and_the_ones_after_apart():
    quiet_ref = [False] * 20
    picked = {wa.SEARCH: [False] * 10 + [True] * 10, "default cell (all of them)": [True] * 20}
    rows = [{"reference": {"pybullet": quiet_ref}, "conditions": picked},
            {"reference": {"pybullet": [True] * 20}, "conditions": picked}]
    got = {g["window"]: g for g in wa.gate_windows(rows)}
    assert got["the search's own, 0-9"]["safe"] == 2          # no failing world among the search's
    assert got["the next ten, 10-19"]["safe"] == 0            # every later one fails
    assert got["the search's own, 0-9"]["safe_mean_ref"] == 0.5 and got["the next ten, 10-19"]["quiet"] == 1


def test_by_gate_failures_groups_plans_by_the_failing_worlds_of_the_gates_first_ten():
    def row(gate_fails: int, ref_fails: int, safe: bool) -> dict:
        worlds = [False] * 10 + [True] * gate_fails + [False] * (10 - gate_fails)
        return {"reference": {"pybullet": [True] * ref_fails + [False] * (20 - ref_fails)},
                "conditions": {wa.SEARCH: worlds}, "declared_safe": safe}

    rows = [row(0, 0, True), row(0, 2, True), row(3, 8, True), row(3, 0, False)]
    got = {g["failed_of_10"]: g for g in wa.by_gate_failures(rows)}
    assert set(got) == {0, 3}
    assert got[0]["plans"] == 2 and got[0]["declared_safe"] == 2 and got[0]["reference_mean"] == 0.05
    assert got[3]["reference_mean"] == 0.2 and got[3]["reference_over_5pct"] == 1 and got[3]["declared_safe"] == 1
    assert got[0]["map_chance"] <= got[3]["map_chance"]        # the shipped map, monotone in the count


def test_mode_conditions_pin_only_the_pull_of_the_default_cell():
    c = wa.mode_conditions()
    assert c["default cell, drag only"] == ({"pull_modes": ("drag",)}, True)
    assert c["default cell, lift only"] == ({"pull_modes": ("lift",)}, True)
    assert c["default cell (all of them)"] == wa.conditions((0.5, 3.0))["default cell (all of them)"]


@pytest.mark.slow
@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_gate_only_rows_carry_the_gates_worlds_and_the_references_failing_draws(tmp_path: Path, capsys):
    if str(JUDGE) not in sys.path:
        sys.path.insert(0, str(JUDGE))
    out = tmp_path / "rows.jsonl"
    argv = ["--kinds", "structured", "--seeds", "41000-41000", "--targets", "1", "--draws", "2", "--gate-only",
            "--mass", "0.5", "3", "--judge", str(JUDGE), "--out", str(out)]
    assert wa.main(argv) == 0
    (row,) = [json.loads(x) for x in out.read_text().splitlines()]
    assert set(row["conditions"]) == set(wa.GATE_ONLY) | {wa.SEARCH}
    assert len(row["conditions"][wa.SEARCH]) == 20            # the search's ten and the gate's first ten
    assert len(row["reference_detail"]) == sum(row["reference"]["pybullet"])
    assert all(d["pulled"] in row["sequence"] for d in row["reference_detail"])
    assert "By the gate's failing worlds" in capsys.readouterr().out


def test_in_expectation_scores_each_risk_and_the_gates_both_sides_over_the_references_draws():
    never, half = [False] * 4, [True, True, False, False]
    rows = [{"reference": {"pybullet": never}, "pinned": [False, True, False, False], "declared_safe": True,
             "conditions": {"x": [False] * 4}},
            {"reference": {"pybullet": half}, "pinned": [True, False, None, False], "declared_safe": True,
             "conditions": {"x": [True] * 4}}]
    e = wa.in_expectation(rows)
    assert e["safe"] == 2 and e["safe_mean_share"] == 0.25 and e["held_safe_share"] == 1.0
    assert e["risky_safe_plans"] == 1 and e["their_failing_draws"] == 2 and e["also_failing_pinned"] == 1
    assert e["only_ours_fail"] == 1 and e["only_reference_fails"] == 1        # the draw without a world is left out
    assert e["auc"]["x"] == 1.0 and e["auc"]["the shipped gate's verdict"] == 0.5
