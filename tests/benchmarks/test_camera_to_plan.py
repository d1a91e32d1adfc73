"""benchmarks/camera_to_plan.py: front-face matching, the id translation, bad arguments, and one real shelf
(s00, one task) rendered by a generator, perceived by the CLI, planned twice and judged by the judge."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
from bench_scripts import JUDGE, ROOT, load

c2p = load("camera_to_plan")


def _box(i: str, x: float, z: float, y: float = 0.1, size=(0.2, 0.2, 0.2)) -> dict:
    return {"id": i, "size": list(size), "position": [x, y, z], "orientation": [1, 0, 0, 0]}


def test_fronts_match_one_to_one_nearest_first_within_half_the_smaller_side() -> None:
    truth = {"boxes": [_box("t0", 0.0, 0.1), _box("t1", 0.2, 0.1), _box("t2", 0.0, 0.3, size=(0.5, 0.2, 0.17))]}
    perceived = {"boxes": [_box("p0", 0.21, 0.1), _box("p1", 0.19, 0.12),      # both nearest t1: one wins
                           _box("p2", 0.0, 0.3 + 0.09, y=0.1),                    # 9 cm off a 17 cm high face
                           _box("p3", 0.01, 0.1, y=0.15, size=(0.2, 0.3, 0.2))]}  # deeper box, same front
    m = c2p.match_fronts(perceived, truth)
    assert m["p0"][0] == "t1" and "p1" not in m
    assert "p2" not in m
    assert m["p3"][0] == "t0" and m["p3"][1] == pytest.approx(0.01, abs=1e-9)


def test_translate_flags_steps_on_boxes_matched_to_nothing() -> None:
    seq, failed = c2p.translate(["p2", "p9", "p0"], {"p0": "b5", "p2": "b1"})
    assert seq == ["b1", c2p.UNMAPPED + "p9", "b5"] and failed == [1]


def test_first_shelves_of_each_kind() -> None:
    assert c2p.plan_shelves(["s00", "s01", "s02", "u00", "u01"], 2) == ["s00", "s01", "u00", "u01"]
    assert c2p.plan_shelves(["s00", "u00"], None) == ["s00", "u00"]


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_bad_arguments_exit_2(capsys) -> None:
    assert c2p.main(["--looks", "glossy"]) == 2
    assert "--looks" in capsys.readouterr().err
    assert c2p.main(["--shelves", "s99"]) == 2
    assert "--shelves" in capsys.readouterr().err
    assert c2p.main(["--judge-dir", str(ROOT)]) == 2
    assert "--judge-dir" in capsys.readouterr().err


@pytest.mark.skipif(not (JUDGE / "judge.py").is_file(), reason="the independent judge is not beside the project")
def test_one_shelf_from_the_image_to_the_judge(tmp_path: Path) -> None:
    out = tmp_path / "rows.jsonl"
    argv = ["--judge-dir", str(JUDGE), "--shelves", "s00", "--looks", "flat", "--max-tasks", "1",
            "--out", str(out)]
    assert c2p.main(argv) == 0
    rows = [json.loads(line) for line in out.read_text().splitlines()]
    assert [r["key"] for r in rows] == ["seen|flat|s00", "true|s00:b5"]
    seen, true = rows
    shelf = seen["shelf"]
    assert shelf["error"] == "" and shelf["true_fronts"] == 8 and shelf["perceived"] >= 1
    assert set(shelf["ids"].values()) <= {f"b{i}" for i in range(8)}
    assert (tmp_path / "rows.frames" / "flat" / "s00" / "perceived.json").is_file()
    (task,) = seen["tasks"]
    assert task["target"] == "b5"
    for plan in (task["physics"], task["highest_first"]):
        if plan.get("error") != "target not perceived":
            assert plan["sequence"][-1] == "b5" and "pybullet" in plan["judges"]
    assert true["plan"]["sequence"][-1] == "b5" and true["plan"]["noise"] == 0.01
    text = out.with_suffix(".md").read_text()
    assert "## look `flat`" in text and "from the image, highest-first" in text
    assert c2p.main(argv + ["--resume"]) == 0          # nothing left to run, the same rows
    assert [json.loads(line)["key"] for line in out.read_text().splitlines()] == ["seen|flat|s00", "true|s00:b5"]
    assert c2p.main(argv[:-2] + ["--out", str(out), "--summary-only", "--no-true"]) == 0   # reads, runs nothing
    assert [json.loads(line)["key"] for line in out.read_text().splitlines()] == ["seen|flat|s00", "true|s00:b5"]


def _plan(ok: bool) -> dict:
    return {"judges": {"pybullet": {"ok": ok}}, "exhaustive": False, "min_removals": None, "kind": "structured",
            "sequence": ["b1"], "declared_safe": False}


def test_tasks_some_plan_can_hold_are_counted_apart(monkeypatch) -> None:
    assert len(c2p.can_hold()) == 98 and "s00:b5" in c2p.can_hold()   # the shipped list
    monkeypatch.setattr(c2p, "can_hold", lambda: frozenset({"s00:b1", "s00:b2"}))
    shelf = {"centre_err": [0.01], "true_fronts": 3, "perceived": 3, "matched_true": 3, "matched": 3,
             "perceive_s": 0.4, "error": ""}
    rows = [{"what": "seen", "look": "stereo", "scene": "s00", "shelf": shelf,
             "tasks": [{"target": "b1", "physics": _plan(True), "highest_first": _plan(False)},
                       {"target": "b2", "physics": _plan(False), "highest_first": _plan(False)},
                       {"target": "b3", "physics": _plan(False), "highest_first": _plan(True)}]},
            {"what": "true", "scene": "s00", "target": "b1", "plan": _plan(True)}]
    s = c2p.summarize(rows, "pybullet")["looks"]["stereo"]
    assert s["can_hold"] == {"physics": [1, 2], "highest_first": [0, 2], "true": [1, 1]}
    assert "of the 2 tasks some plan can hold on the true shelf" in c2p.to_markdown(c2p.summarize(rows, "pybullet"), "")
