"""benchmarks/stand_check.py: one shelf's check as the planner builds it, and a bad judge folder."""
from __future__ import annotations

from pathlib import Path

import pytest
from bench_scripts import JUDGE, load

sc = load("stand_check")


def test_a_judge_folder_without_scenes_exits_2(tmp_path: Path, capsys) -> None:
    assert sc.main(["--judge", str(tmp_path)]) == 2
    assert "--judge" in capsys.readouterr().err


@pytest.mark.skipif(not (JUDGE / "observe.py").is_file(), reason="the independent judge is not beside the project")
def test_an_exact_shelf_stands_as_seen(tmp_path: Path) -> None:
    from benchmarks.judge_rows import init_worker

    init_worker(str(JUDGE))
    row = sc.check_shelf(JUDGE, "s00", 0.0, 2, tmp_path)
    assert row == {"scene": "s00", "stands_as_seen": True, "problems": []}
