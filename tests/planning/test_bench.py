"""The benchmark's orchestration: same records serially, with workers and on Ray; resume; report formulas."""
from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.planning.bench import (BenchConfig, RecordLog, comparable, derive_seed, read_records, run_bench,
                            summarize, to_markdown)

SHELF = Shelf(1.0, 0.30, 1.60)


def _tiny_scene(kind: str, stacked: bool) -> Scene:
    """Two or three cubes: side by side, or one on top of another (a real collapse risk)."""
    boxes = [Box("b0", (0.2, 0.2, 0.2), (-0.2, 0.1, 0.1)), Box("b1", (0.2, 0.2, 0.2), (0.2, 0.1, 0.1))]
    if stacked:
        boxes.append(Box("b2", (0.2, 0.2, 0.2), (-0.2, 0.1, 0.301)))
    return Scene(SHELF, tuple(boxes), source={"kind": kind})


@pytest.fixture()
def scenes_dir(tmp_path: Path) -> Path:
    d = tmp_path / "scenes"
    d.mkdir()
    _tiny_scene("structured", True).save(d / "s-a.json")
    _tiny_scene("unstructured", False).save(d / "u-b.json")
    return d


def fake_job(job) -> list[dict]:
    """A cheap deterministic stand-in for run_scene: the orchestration is what is tested."""
    out = []
    for t in job.targets:
        s = derive_seed(job.config.seed, job.name, t)
        out.append({"key": f"{job.name}:{t}", "scene": job.name, "kind": job.doc["source"]["kind"],
                    "n_boxes": len(job.doc["boxes"]), "target": t, "seed": s,
                    "planners": {p: {"ok": s % 3 != 0, "removed": 1 + s % 2, "plan_s": 0.01,
                                     "mean_disp": 0.0, "sequence": [t]} for p in job.config.planners}})
    return out


CFG = BenchConfig(("physics", "heuristic"), samples=2, seed=3, exhaustive_max_boxes=3)


def _untimed(table: dict) -> dict:
    return {k: {p: {m: v for m, v in r.items() if not m.startswith("plan_p")} for p, r in t.items()}
            for k, t in table.items()}


def test_serial_equals_workers_real_planning(scenes_dir: Path, tmp_path: Path) -> None:
    a = run_bench(scenes_dir, tmp_path / "serial", CFG, progress=False)
    b = run_bench(scenes_dir, tmp_path / "workers", CFG, workers=2, progress=False)
    ra, rb = read_records(tmp_path / "serial" / "records.jsonl"), read_records(tmp_path / "workers" / "records.jsonl")
    assert len(ra) == 5
    assert comparable(ra) == comparable(rb)
    assert _untimed(a["table"]) == _untimed(b["table"])
    # side-by-side cubes: the physics plan takes just the target, and it works on the true scene
    for r in ra:
        if r["scene"] == "u-b":
            assert r["planners"]["physics"]["ok"] and r["planners"]["physics"]["removed"] == 1
    # exhaustive ground truth ran on these small scenes
    assert all("exhaustive" in r for r in ra)
    top = next(r for r in ra if r["key"] == "s-a:b0")  # the box under b2
    assert top["exhaustive"]["feasible"] and top["exhaustive"]["min_removals"] == 2
    for f in ("results.md", "results.json", "results.png"):
        assert (tmp_path / "serial" / f).stat().st_size > 0


def test_ray_equals_serial(scenes_dir: Path, tmp_path: Path) -> None:
    ray = pytest.importorskip("ray")
    from ray import cloudpickle
    import sys
    cloudpickle.register_pickle_by_value(sys.modules[__name__])
    run_bench(scenes_dir, tmp_path / "serial", CFG, fn=fake_job, progress=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        run_bench(scenes_dir, tmp_path / "ray", CFG, fn=fake_job, ray_address="auto", progress=False)
    finally:
        ray.shutdown()
    ra = read_records(tmp_path / "serial" / "records.jsonl")
    rb = read_records(tmp_path / "ray" / "records.jsonl")
    assert len(ra) == 5 and comparable(ra) == comparable(rb)


@pytest.mark.slow
def test_ray_equals_serial_real_planning(scenes_dir: Path, tmp_path: Path) -> None:
    ray = pytest.importorskip("ray")
    run_bench(scenes_dir, tmp_path / "serial", CFG, progress=False)
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        run_bench(scenes_dir, tmp_path / "ray", CFG, ray_address="auto", progress=False)
    finally:
        ray.shutdown()
    assert comparable(read_records(tmp_path / "serial" / "records.jsonl")) == \
        comparable(read_records(tmp_path / "ray" / "records.jsonl"))


def test_resume_skips_done_tasks(scenes_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "out"
    run_bench(scenes_dir, out, CFG, fn=fake_job, progress=False, limit=1)
    first = read_records(out / "records.jsonl")
    assert {r["scene"] for r in first} == {"s-a"}
    # a crash mid-write leaves a torn line: it is dropped and the log continues cleanly
    with open(out / "records.jsonl", "a") as f:
        f.write('{"key": "u-b:b0", "trunc')
    calls = []

    def counting(job):
        calls.append((job.name, job.targets))
        return fake_job(job)

    s = run_bench(scenes_dir, out, CFG, fn=counting, progress=False)
    assert calls == [("u-b", ("b0", "b1"))]        # only what was missing
    lines = (out / "records.jsonl").read_text().splitlines()
    keys = [json.loads(x)["key"] for x in lines]
    assert sorted(keys) == sorted(set(keys)) and len(keys) == 5
    assert s["tasks"] == 5
    calls.clear()
    run_bench(scenes_dir, out, CFG, fn=counting, progress=False)
    assert calls == []


def test_resume_mid_scene_is_exact(scenes_dir: Path, tmp_path: Path) -> None:
    """A run stopped after part of a scene's records continues to the same records as an unbroken run
    (every trial is a pure function of its seed, not of what the scene's Predictor ran before)."""
    full = tmp_path / "full"
    run_bench(scenes_dir, full, CFG, progress=False)
    whole = read_records(full / "records.jsonl")
    cut = tmp_path / "cut"
    cut.mkdir()
    shutil.copy(full / "run.json", cut / "run.json")
    kept = [r for r in whole if r["key"] in ("s-a:b1",)]   # only the middle target of the first scene
    (cut / "records.jsonl").write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in kept))
    run_bench(scenes_dir, cut, CFG, progress=False)
    again = read_records(cut / "records.jsonl")
    assert comparable(again) == comparable(whole)


def test_resume_refuses_records_of_a_changed_scene(scenes_dir: Path, tmp_path: Path) -> None:
    from shelfpick.perception.errors import ShelfpickError
    out = tmp_path / "o"
    run_bench(scenes_dir, out, CFG, fn=fake_job, progress=False, limit=1)
    with open(out / "records.jsonl") as f:
        recs = [json.loads(x) for x in f]
    (out / "records.jsonl").write_text("".join(json.dumps({**r, "scene_sha": "0" * 16}) + "\n" for r in recs))
    with pytest.raises(ShelfpickError, match="different file"):
        run_bench(scenes_dir, out, CFG, fn=fake_job, progress=False)


def test_rerun_with_other_settings_is_refused(scenes_dir: Path, tmp_path: Path) -> None:
    from shelfpick.perception.errors import ShelfpickError
    run_bench(scenes_dir, tmp_path / "o", CFG, fn=fake_job, progress=False, limit=1)
    with pytest.raises(ShelfpickError, match="another --out"):
        run_bench(scenes_dir, tmp_path / "o", BenchConfig(samples=5), fn=fake_job, progress=False)


def _rec(key, kind, pa, bh, exh=None):
    r = {"key": key, "scene": key.split(":")[0], "kind": kind, "target": "b0", "n_boxes": 5,
         "planners": {"physics": {"ok": pa[0], "removed": pa[1], "plan_s": pa[2], "mean_disp": 0.001},
                      "heuristic": {"ok": bh[0], "removed": bh[1], "plan_s": 0.0, "mean_disp": 0.004}}}
    if exh is not None:
        r["exhaustive"] = {"feasible": exh is not False, "min_removals": exh or None}
    return r


def test_report_formulas_on_hand_made_records() -> None:
    recs = [_rec("a:b0", "structured", (True, 1, 0.1), (True, 3, 0.0), exh=1),
            _rec("a:b1", "structured", (True, 2, 0.3), (False, 4, 0.0), exh=1),
            _rec("b:b0", "unstructured", (False, 2, 0.5), (False, 2, 0.0), exh=False),
            _rec("b:b1", "unstructured", (True, 1, 0.9), (True, 4, 0.0))]
    s = summarize(recs, BenchConfig(robot_time=10.0))
    st = s["table"]["structured"]
    assert st["physics"]["success_rate"] == 1.0 and st["heuristic"]["success_rate"] == 0.5
    assert st["physics"]["mean_removed"] == 1.5 and st["physics"]["mean_exec_time_s"] == 15.0
    assert st["heuristic"]["mean_exec_time_s"] == 35.0
    assert st["relative"]["efficiency"] == pytest.approx((35.0 - 15.0) / 15.0)
    assert st["physics"]["plan_p50_s"] == pytest.approx(0.2) and st["physics"]["plan_p90_s"] == pytest.approx(0.28)
    assert st["physics"]["mean_disp_per_step_m"] == pytest.approx(0.001)
    allk = s["table"]["all"]
    assert allk["physics"]["tasks"] == 4 and allk["physics"]["success_rate"] == 0.75
    e = s["exhaustive"]
    assert e["tasks"] == 3 and e["feasible_tasks"] == 2
    assert e["physics"]["success_rate_on_feasible"] == 1.0
    assert e["physics"]["mean_gap_removals"] == pytest.approx(0.5)   # (1-1 + 2-1) / 2
    assert e["heuristic"]["success_rate_on_feasible"] == 0.5
    md = to_markdown(s)
    assert "| structured | physics | 2 | 100.0% | 1.50 | 15.0 |" in md
    assert "+133.3%" in md


def test_record_log_cuts_torn_line(tmp_path: Path) -> None:
    p = tmp_path / "r.jsonl"
    p.write_text('{"key": "x:b0"}\n{"key": "x:b1", "pla')
    log = RecordLog(p)
    log.write([{"key": "x:b2"}])
    log.close()
    assert [r["key"] for r in read_records(p)] == ["x:b0", "x:b2"]


def test_seeds_do_not_depend_on_order() -> None:
    assert derive_seed(0, "s", "b1") == derive_seed(0, "s", "b1")
    assert derive_seed(0, "s", "b1") != derive_seed(1, "s", "b1")
    assert derive_seed(0, "s", "b1") != derive_seed(0, "s", "b2")


def test_bench_cli_bad_input(tmp_path: Path, capsys) -> None:
    from shelfpick.console.cli import main
    assert main(["bench", str(tmp_path / "missing"), "--out", str(tmp_path / "o")]) == 2
    assert "not a folder" in capsys.readouterr().err
    assert main(["bench", str(tmp_path), "--planners", "physics,magic"]) == 2
    assert "magic" in capsys.readouterr().err
    (tmp_path / "bad.json").write_text('{"format": "shelfpick.scene/1", "shelf": {"width": 1, "depth": 0.3, "height": 1.6}, "boxes": [{"id": "b0", "size": [0, 1, 1], "position": [0, 0.1, 0.1]}]}')
    assert main(["bench", str(tmp_path), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert "bad.json" in err and "size" in err


# --------------------------------------------------------------------------
# the perturbed truth (issue 9): what the planner sees, and the shelf it really meets
def test_observe_gives_front_faces_only_with_seeded_error() -> None:
    from shelfpick.planning.bench import observe

    truth = _tiny_scene("structured", True).with_boxes(
        [Box(b.id, b.size, b.position, b.orientation, 2.0) for b in _tiny_scene("structured", True).boxes])
    exact = observe(truth, 0.0, 1)
    for t, o in zip(truth.boxes, exact.boxes):
        assert o.mass is None and not o.depth_known and o.size[1] == pytest.approx(0.10)
        assert o.front_center == pytest.approx(t.front_center)           # the face is kept exactly
        assert o.size[0] == t.size[0] and o.size[2] == t.size[2]
    a, b, c = observe(truth, 0.01, 1), observe(truth, 0.01, 1), observe(truth, 0.01, 2)
    assert a.to_json() == b.to_json() and a.to_json() != c.to_json()
    err = [abs(x - y) for t, o in zip(truth.boxes, a.boxes) for x, y in zip(t.front_center, o.front_center)]
    assert 0.0 < max(err) < 0.05


def test_truth_draw_is_seeded_keeps_given_masses_and_drags() -> None:
    from shelfpick.planning.bench import TruthModel, draw_truth

    scene = _tiny_scene("structured", True)
    scene = scene.with_boxes([Box(b.id, b.size, b.position, b.orientation, 4.0 if b.id == "b0" else None)
                              for b in scene.boxes])
    model = TruthModel()
    world, physics = draw_truth(scene, model, 7)
    assert world.boxes[0].mass == 4.0
    assert all(0.3 <= b.mass <= 5.0 for b in world.boxes[1:])
    assert 0.5 <= physics.lateral_friction <= 0.9 and 0.15 <= physics.pull_speed <= 0.35
    assert 100 <= physics.pull_force <= 200 and physics.pull_lift == 0.0
    again, physics2 = draw_truth(scene, model, 7)
    assert again.to_json() == world.to_json() and physics2 == physics
    assert draw_truth(scene, model, 8)[1] != physics
    # the bench's drag lets the box ride on its support; `pull_hold` holds its height, as the worlds' drag does
    assert physics.pull_hold is False
    _, held = draw_truth(scene, TruthModel(pull_hold=True), 7)
    assert held.pull_hold is True and held.lateral_friction == physics.lateral_friction


def test_true_world_refuses_a_shelf_that_cannot_stand() -> None:
    from shelfpick.perception.errors import SceneError
    from shelfpick.planning.bench import TruthModel, true_world

    _, _, draw = true_world(_tiny_scene("structured", True), TruthModel(), 3)
    assert draw == 0
    # a cube hanging 15 cm over the edge of the one below it falls whatever the draw
    tipping = Scene(SHELF, (Box("b0", (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)),
                            Box("b1", (0.2, 0.2, 0.2), (0.15, 0.1, 0.301))))
    with pytest.raises(SceneError, match="does not stand under any of 2 truth draws"):
        true_world(tipping, TruthModel(draws=2), 3)


def test_report_counts_declared_safe_collapses_and_scenes_without_truth() -> None:
    recs = [_rec("a:b0", "proud", (True, 1, 0.1), (False, 3, 0.0), exh=False),
            _rec("a:b1", "proud", (False, 2, 0.3), (True, 4, 0.0), exh=1),
            {"key": "c:b0", "scene": "c", "kind": "lean", "target": "b0", "planners": {}, "no_truth": "b1 moved"}]
    for r in recs[:2]:
        r["planners"]["physics"]["safe"] = True
        r["planners"]["heuristic"]["safe"] = False
    s = summarize(recs, BenchConfig(robot_time=10.0))
    assert s["tasks"] == 2 and s["no_truth"] == {"tasks": 1, "scenes": ["c"]}
    assert s["table"]["proud"]["physics"]["declared_safe"] == 2
    assert s["table"]["proud"]["physics"]["declared_safe_collapsed"] == 1
    assert s["exhaustive"]["heuristic"]["infeasible_flagged"] == 1
    assert s["exhaustive"]["physics"]["infeasible_flagged"] == 0
    md = to_markdown(s)
    assert "1/2 (50%)" in md and "Not judged: 1 tasks on 1 scenes" in md and "perception error" in md
    assert "Highest-first fails on: proud 1/2 (50%)." in md
