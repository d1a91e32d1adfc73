"""benchmarks/perceive_generated.py's sample check (issue 31): a perceived scene the planner cannot
build sample worlds of is counted, with the planner's reason."""
from __future__ import annotations

from bench_scripts import load

from shelfpick.perception.scene import Box, Scene, Shelf


def _scene(second_x: float) -> Scene:
    def box(i: str, x: float) -> Box:
        return Box(i, (0.2, 0.25, 0.2), (x, 0.125, 0.1), (1.0, 0.0, 0.0, 0.0), None, False, 1, {})
    return Scene(Shelf(), (box("b0", 0.0), box("b1", second_x)))


def test_sample_check_counts_the_planners_refusals_with_its_reason():
    pg = load("perceive_generated")
    assert pg.sample_check(_scene(0.2), samples=2) == []
    refused = pg.sample_check(_scene(0.13), samples=2)          # 7 cm into each other: past repair
    assert len(refused) == 2 and all("no draw of sample" in r and "overlap" in r for r in refused)


def test_held_out_looks_and_other_seeds_are_refused(capsys):
    pg = load("perceive_generated")
    assert pg.main(["--look", "stereo", "--out", "/nonexistent"]) == 2
    assert pg.main(["--seeds", "31060", "--out", "/nonexistent"]) == 2
    assert pg.main(["--seeds", "31a", "--out", "/nonexistent"]) == 2     # a one-line refusal, no traceback
    assert "tuning" in capsys.readouterr().err
