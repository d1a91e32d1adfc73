"""benchmarks/perceive_speed.py (issue 31's speed figure): the fingerprint comparison that shows a
speed-up changed no output; of the held-out frames' outputs a fingerprint keeps only a hash, and they
are never profiled."""
from __future__ import annotations

import copy

from bench_scripts import load


def _fp() -> dict:
    scene = {"boxes": [{"id": "b0", "position": [0.1, 0.2, 0.3], "size": [0.2, 0.25, 0.2]}], "unexplained": []}
    return {"flat/31000": {"scene": scene, "faces": [], "warnings": ["w"], "adjustments": [], "masks": "ab",
                           "unexplained_labels": "none", "overlay": "cd", "cpu_s": 0.5}}


def test_compare_tells_byte_equal_close_and_different_frames_apart():
    ps = load("perceive_speed")
    a = _fp()
    b = copy.deepcopy(a)
    b["flat/31000"]["cpu_s"] = 0.2                       # time is not an output
    assert ps.compare(a, b) == (1, [], [])
    b["flat/31000"]["scene"]["boxes"][0]["position"][0] += 1e-12
    assert ps.compare(a, b) == (0, ["flat/31000"], [])
    b["flat/31000"]["scene"]["boxes"][0]["position"][0] += 1e-6
    assert ps.compare(a, b) == (0, [], ["flat/31000"])
    c = copy.deepcopy(a)
    c["flat/31000"]["warnings"] = ["other"]
    assert ps.compare(a, c) == (0, [], ["flat/31000"])
    assert ps.compare(a, {}) == (0, [], ["flat/31000"])    # a frame missing from one side


def test_a_held_out_frames_fingerprint_is_a_hash_that_only_tells_equal_from_different():
    ps = load("perceive_speed")
    doc = {k: v for k, v in _fp()["flat/31000"].items() if k != "cpu_s"}
    assert ps.kept("flat", doc) == doc                    # a tuning frame: everything
    held = ps.kept("printed", doc)
    assert list(held) == ["digest"] and "b0" not in held["digest"]
    other = copy.deepcopy(doc)
    other["scene"]["boxes"][0]["position"][0] += 1e-12
    a, b, c = ({"printed/s00": dict(ps.kept("printed", d), cpu_s=0.1)} for d in (doc, copy.deepcopy(doc), other))
    assert ps.compare(a, b) == (1, [], [])
    assert ps.compare(a, c) == (0, [], ["printed/s00"])   # no "within 1e-9" for a hash


def test_held_out_frames_are_never_profiled(capsys, tmp_path):
    ps = load("perceive_speed")
    judge = tmp_path / "judge"
    (judge / "scenes").mkdir(parents=True)
    assert ps.main(["--judge-dir", str(judge), "--profile", str(tmp_path / "p.prof")]) == 2
    assert ps.main(["--judge-dir", str(tmp_path / "none")]) == 2
    err = capsys.readouterr().err
    assert "--profile: only on --set tune" in err and "has no scenes/" in err


def test_shelves_that_are_not_in_the_set_are_refused_in_one_line(capsys, tmp_path):
    ps = load("perceive_speed")
    judge = tmp_path / "judge"
    (judge / "scenes").mkdir(parents=True)
    (judge / "scenes" / "s00.json").write_text("{}")
    frames = str(tmp_path / "frames")
    assert ps.main(["--set", "tune", "--shelves", "31000-31001x", "--frames", frames]) == 2
    assert ps.main(["--set", "tune", "--shelves", "29999", "--frames", frames]) == 2
    assert ps.main(["--judge-dir", str(judge), "--shelves", "s00,zz", "--frames", frames]) == 2
    err = capsys.readouterr().err.splitlines()
    assert err == ["perceive_speed: --shelves: expected A-B or a comma list, got '31000-31001x'",
                   "perceive_speed: --shelves: 29999 is not a tuning shelf (only the tuning seeds 31000-31059)",
                   "perceive_speed: --shelves: unknown shelf 'zz' (the judge has s00..s00)"]
    assert not (tmp_path / "frames").exists()


def test_paired_gives_the_median_of_each_frames_after_over_before():
    ps = load("perceive_speed")

    def row(look, wall, cpu):
        return {"look": look, "shelf": "s", "wall": {"perceive": wall}, "cpu": {"perceive": cpu}}

    both = {"before": [row("printed", 1.0, 1.0), row("printed", 2.0, 1.0), row("stereo", 1.0, 2.0)],
            "after": [row("printed", 0.5, 0.8), row("printed", 1.0, 0.9), row("stereo", 0.9, 1.0)]}
    lines = ps.paired(both).splitlines()
    assert lines[2] == "| printed | 2 | 0.500 | 0.850 |"
    assert lines[3] == "| stereo | 1 | 0.900 | 0.500 |"
    assert lines[4].startswith("| all | 3 | 0.500 |")


def test_a_timed_process_may_cache_its_bytecode_outside_the_repo(monkeypatch, tmp_path):
    ps = load("perceive_speed")
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    assert ps.child_env(None) is None                        # as this process's environment
    env = ps.child_env(str(tmp_path / "pyc"))
    assert "PYTHONDONTWRITEBYTECODE" not in env and env["PYTHONPYCACHEPREFIX"] == str(tmp_path / "pyc")


def test_the_split_of_a_process_gives_each_phase_over_frames():
    ps = load("perceive_speed")
    rows = [{"look": "printed", "shelf": s, "wall": {k: t for k in ps.SPLIT}} for s, t in (("a", 0.1), ("b", 0.3))]
    lines = ps.split_summary(rows).splitlines()
    assert lines[2] == "| interpreter | 0.200 | 0.280 | 0.200 |"
    assert [ln.split(" | ")[0] for ln in lines[2:2 + len(ps.SPLIT)]] == [f"| {k}" for k in ps.SPLIT]


def test_another_commits_tree_is_imported_as_shelfpick_ahead_of_the_installed_one(tmp_path):
    import subprocess
    import sys

    ps = load("perceive_speed")
    tree = tmp_path / "old"
    for part in ("shelfpick", "perception", "planning", "console", "robotsim", "static"):
        (tree / part).mkdir(parents=True)
    (tree / "shelfpick" / "__init__.py").write_text("")
    (tree / "perception" / "__init__.py").write_text("WHO = 'the old tree'\n")
    env = ps.tree_env(str(tree), None)
    assert env["PYTHONSAFEPATH"] == "1"
    out = subprocess.run([sys.executable, "-c", "import shelfpick.perception as p; print(p.WHO)"], env=env,
                         capture_output=True, text=True, cwd=ps.ROOT)     # the checkout's own shelfpick/ beside
    assert out.stdout.strip() == "the old tree", out.stderr


def test_two_cli_runs_outputs_are_equal_or_not_the_reports_timing_aside(tmp_path):
    import json

    ps = load("perceive_speed")
    for side, (total, masks) in {"before": (1.5, b"m"), "after": (0.9, b"m")}.items():
        d = tmp_path / side / "printed" / "s00"
        d.mkdir(parents=True)
        (d / "perceived.json").write_text('{"boxes": []}')
        (d / "perceived_masks.png").write_bytes(masks)
        (d / "overlay.png").write_bytes(b"o")
        (d / "report.json").write_text(json.dumps({"warnings": [], "timing": {"total": total}}))
    assert ps.compare_outputs(tmp_path / "before", tmp_path / "after") == (1, [])
    (tmp_path / "after" / "printed" / "s00" / "perceived_masks.png").write_bytes(b"other")
    assert ps.compare_outputs(tmp_path / "before", tmp_path / "after") == (0, ["printed/s00"])
    (tmp_path / "after" / "printed" / "s00" / "report.json").unlink()       # missing on one side
    assert ps.compare_outputs(tmp_path / "before", tmp_path / "after") == (0, ["printed/s00"])


def test_with_and_without_the_bytecode_cache_needs_the_cache_folder(capsys, tmp_path):
    ps = load("perceive_speed")
    (tmp_path / "judge" / "scenes").mkdir(parents=True)
    assert ps.main(["--judge-dir", str(tmp_path / "judge"), "--mode", "cli", "--ab-pycache"]) == 2
    assert "--ab-pycache needs --pycache DIR" in capsys.readouterr().err


def test_a_stage_on_another_thread_is_timed_on_it_and_left_out_of_other(monkeypatch):
    """The depth rules run beside the network (a thread of their own): their time is theirs, their
    stack is their thread's, and `other` (perceive's untapped rest) does not subtract it again."""
    import sys
    import threading
    import time
    import types

    ps = load("perceive_speed")
    mod = types.ModuleType("fake_stages")

    def rules():
        time.sleep(0.05)

    def net():
        t = threading.Thread(target=mod.rules)
        t.start()
        time.sleep(0.05)
        t.join()

    mod.rules, mod.net = rules, net
    monkeypatch.setitem(sys.modules, "fake_stages", mod)
    monkeypatch.setattr(ps, "STAGES", (("forward", "fake_stages", "net"), ("depth_rules", "fake_stages", "rules")))
    taps = ps.Taps()
    try:
        w = time.perf_counter()
        mod.net()
        pw = time.perf_counter() - w
    finally:
        taps.close()
    assert taps.wall["depth_rules"] >= 0.045 and taps.wall["forward"] >= 0.045
    assert set(taps.beside) == {"depth_rules"} and taps.beside["depth_rules"] == taps.wall["depth_rules"]
    other = pw - (sum(taps.wall.values()) - sum(taps.beside.values()))
    assert 0 <= other < 0.03            # the two stages overlap: not 0.05 s below zero
    assert mod.net is net and mod.rules is rules
