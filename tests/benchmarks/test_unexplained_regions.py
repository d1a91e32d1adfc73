"""benchmarks/unexplained_regions.py on one tuning frame: no false region on the true faces, and the
region a removed box leaves is found where it stands."""
from __future__ import annotations

from benchmarks.unexplained_regions import frames, one, summary


def test_one_tuning_frame_has_no_false_region_and_finds_the_removed_box():
    name, look, truth = next(frames("tune"))
    assert (name, look) == ("31000", "flat")
    row = one(name, look, truth, perceive_too=False)
    assert row["exact_regions"] == 0 and row["less_one_regions"] == 1 and row["less_one_found"]
    s = summary([row])["flat"]
    assert s == {"frames": 1, "frames_with_a_false_region": 0, "false_regions": 0, "missing_box_found": 1,
                 "missing_box_extra_regions": 0}
