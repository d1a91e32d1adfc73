"""benchmarks/pull_artefacts.py: Coulomb's moments of a column with a box dragged off its top."""
from __future__ import annotations

from bench_scripts import load

from shelfpick.perception.scene import Box, Scene, Shelf

pa = load("pull_artefacts")


def _column(top_mass: float) -> Scene:
    cube = (0.2, 0.2, 0.2)
    return Scene(Shelf(width=1.0, depth=0.3, height=1.0), (
        Box("low", cube, (0.0, 0.10, 0.1), mass=1.0),
        Box("top", cube, (0.0, 0.12, 0.3), mass=top_mass)))


def test_column_moments_by_hand():
    # pivot: low's front edge at y 0.0; the drag acts at low's top, 0.2 m up; contact friction 0.5^2
    got = pa.column_moments(_column(2.0), "top", ["low"], friction=0.5, gravity=10.0)
    assert got == {"tipping_nm": round(0.25 * 2.0 * 10.0 * 0.2, 2),
                   "restoring_nm": round(1.0 * 10.0 * 0.10 + 2.0 * 10.0 * 0.12, 2)}


def test_a_heavier_box_on_top_tips_a_column_its_restoring_moment_holds_when_light():
    light = pa.column_moments(_column(0.5), "top", ["low"], friction=0.9, gravity=9.81)
    heavy = pa.column_moments(_column(20.0), "top", ["low"], friction=0.9, gravity=9.81)
    assert light["tipping_nm"] < light["restoring_nm"] and heavy["tipping_nm"] > heavy["restoring_nm"]
