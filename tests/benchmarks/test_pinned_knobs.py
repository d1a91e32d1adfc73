"""benchmarks/pinned_knobs.py: it picks the draws our pinned worlds fail of plans the reference holds
in every draw, its variants are physics settings that exist, and a bad rows file exits 2."""
from __future__ import annotations

from dataclasses import fields
from pathlib import Path

from bench_scripts import load

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
