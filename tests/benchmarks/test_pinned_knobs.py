"""benchmarks/pinned_knobs.py: it picks the draws our pinned worlds fail of plans the reference holds
in every draw, its variants are physics settings that exist, and a bad rows file exits 2."""
from __future__ import annotations

from dataclasses import fields
from pathlib import Path

import pytest
from bench_scripts import JUDGE, load

pk = load("pinned_knobs")


def test_it_picks_only_our_failures_on_plans_the_reference_always_holds():
    rows = [{"reference": {"pybullet": [False] * 3}, "pinned": [True, False, True]},
            {"reference": {"pybullet": [False, True, False]}, "pinned": [True, True, True]},
            {"reference": {"pybullet": [False] * 3}, "pinned": [False, None, False]}]
    got = pk.false_alarms(rows, limit=10)
    assert [(rows.index(r), d) for r, d in got] == [(0, 0), (0, 2)]
    assert len(pk.false_alarms(rows, limit=1)) == 1


def test_every_variant_changes_settings_our_physics_has():
    from shelfpick.planning.physics import PhysicsConfig

    known = {f.name for f in fields(PhysicsConfig)}
    assert pk.VARIANTS["as is"] == {}
    assert all(set(v) <= known for v in pk.VARIANTS.values())


def test_a_missing_rows_file_exits_2(tmp_path: Path, capsys):
    assert pk.main([str(tmp_path / "none.jsonl")]) == 2
    assert "none.jsonl" in capsys.readouterr().err


@pytest.mark.skipif(not (JUDGE / "judge_mujoco.py").is_file(), reason="the independent judge is not beside the project")
def test_one_draw_runs_our_variants_and_the_judges_mujoco_engine_on_that_draws_masses():
    """The pinned world as world_ablation builds it (its 'as is' variant gives world_ablation's pinned
    verdict), and MuJoCo's verdict for each draw in turn equals world_ablation's reference over all."""
    import sys

    from shelfpick.planning.shelves import generate

    wa = load("world_ablation")
    if str(JUDGE) not in sys.path:
        sys.path.insert(0, str(JUDGE))
    truth = generate("structured", 41000, settle=True)
    row = {"shelf": "structured-41000", "target": "b0", "sequence": ["b0"]}
    unit = {"target": "b0", "sequence": ["b0"], "draws": 2, "seed": 41000, "mass": (0.5, 3.0)}
    ref = wa.reference_fails(truth.to_json(), unit, "mujoco")
    assert [pk.mujoco_fails(truth.to_json(), row, d, (0.5, 3.0), str(JUDGE)) for d in (0, 1)] == ref
    got = pk.run_draw(truth, row, 1, (0.5, 3.0))
    assert set(got) == set(pk.VARIANTS) and got["as is"] == wa.pinned_fails(truth, unit)[1]


def test_confusion_puts_each_draw_on_one_side_of_the_reference():
    rows = [{"reference": {"pybullet": [True, True, False, False, False]},
             "pinned": [True, False, True, False, None]}]
    got = pk.wa.confusion(rows, lambda r: r["pinned"])
    assert got == {"both fail": 1, "reference fails, ours holds": 1, "reference holds, ours fails": 1,
                   "both hold": 1, "no rest": 1}
    flipped = pk.wa.confusion(rows, lambda r: [not f if f is not None else None for f in r["pinned"]])
    assert flipped["both fail"] == 1 and flipped["reference holds, ours fails"] == 1
    assert flipped["reference fails, ours holds"] == 1 and flipped["both hold"] == 1


def test_both_sides_as_is_gives_world_ablations_pinned_verdicts():
    wa = load("world_ablation")
    from shelfpick.planning.shelves import generate

    rows = [{"shelf": "structured-41000", "target": t, "sequence": [t], "draws": 2} for t in ("b0", "b1")]
    got = pk.both_sides_unit({"shelf": "structured-41000", "rows": rows, "variant": "as is", "mass": [0.5, 3.0]})
    truth = generate("structured", 41000, settle=True)
    for plan, t in zip(got, ("b0", "b1")):
        unit = {"target": t, "sequence": [t], "draws": 2, "seed": 41000, "mass": (0.5, 3.0)}
        assert plan["fails"] == wa.pinned_fails(truth, unit)
        assert plan["variant"] == "as is" and plan["sequence"] == [t]
