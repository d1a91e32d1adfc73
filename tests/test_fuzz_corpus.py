"""The bad-input corpus (tests/fuzz_corpus/) through the real CLI: every case is exit 2 and one
stderr line naming the file and the field (or what is wrong with the file), within 10 s.

All cases run in-process through `console.cli.main` (the same code path as the `shelfpick`
script: argument parsing, the subcommand, the one-line error); a representative dozen also as
real subprocesses, and the whole corpus as subprocesses with `-m slow`.
"""
from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from shelfpick.console.cli import main

ROOT = Path(__file__).resolve().parent.parent
CORPUS = ROOT / "tests" / "fuzz_corpus"
MANIFEST: dict[str, dict] = json.loads((CORPUS / "cases.json").read_text())
SECONDS = 10.0
# one or two of each kind: scene, plan, camera, image, masks, special files
REPRESENTATIVE = ["scene-nested-100k", "scene-digits-5000-size", "scene-10000-boxes", "scene-fifo",
                  "scene-nan-in-extra", "scene-box-behind-wall", "plan-sequence-unknown-box", "plan-nan-timing",
                  "camera-fx-negative", "camera-device", "depth-flat", "masks-key-not-integer"]

sys.path.insert(0, str(CORPUS))
import make_corpus  # noqa: E402


def argv_for(name: str, tmp: Path) -> tuple[list[str], str]:
    """The case's command line and the file its error must name, placeholders filled in."""
    case = MANIFEST[name]
    if case.get("special"):
        make_corpus.make_special(name, tmp)
    fill = {"good": str(CORPUS / "good"), "case": str(CORPUS / "cases" / name), "tmp": str(tmp)}
    return [a.format(**fill) for a in case["argv"]], case["names"].format(**fill)


def judge(name: str, rc: int, err: str, seconds: float, names: str) -> None:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert rc == 2, (name, rc, err)
    assert len(lines) == 1, (name, err)
    assert names in lines[0] and MANIFEST[name]["says"] in lines[0], (name, lines[0])
    assert "Traceback" not in err
    assert seconds < SECONDS, (name, seconds)


def test_the_corpus_has_at_least_60_cases_of_each_file_kind() -> None:
    kinds = {n.split("-")[0] for n in MANIFEST}
    assert len(MANIFEST) >= 60 and {"scene", "plan", "camera", "rgb", "depth", "npy", "masks"} <= kinds
    commands = {c["argv"][0] for c in MANIFEST.values()}
    assert commands == {"plan", "simulate", "perceive"}


def test_the_committed_corpus_is_what_make_corpus_writes(tmp_path: Path) -> None:
    fresh = make_corpus.write(tmp_path)
    assert fresh == MANIFEST
    for f in (tmp_path / "cases").rglob("*"):
        if f.is_file():
            assert (CORPUS / f.relative_to(tmp_path)).read_bytes() == f.read_bytes(), f


@pytest.mark.parametrize("name", sorted(MANIFEST))
def test_case_in_process(name: str, tmp_path: Path, capsys) -> None:
    argv, names = argv_for(name, tmp_path)
    t0 = time.monotonic()
    rc = main(argv)
    seconds = time.monotonic() - t0
    judge(name, rc, capsys.readouterr().err, seconds, names)


def _subprocess(name: str, tmp_path: Path) -> None:
    argv, names = argv_for(name, tmp_path)
    t0 = time.monotonic()
    p = subprocess.run([sys.executable, "-m", "shelfpick.console.cli", *argv], cwd=ROOT, capture_output=True, text=True,
                       timeout=SECONDS + 20)
    judge(name, p.returncode, p.stderr, time.monotonic() - t0, names)


@pytest.mark.parametrize("name", REPRESENTATIVE)
def test_case_as_a_subprocess(name: str, tmp_path: Path) -> None:
    _subprocess(name, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(MANIFEST) - set(REPRESENTATIVE)))
def test_every_case_as_a_subprocess(name: str, tmp_path: Path) -> None:
    _subprocess(name, tmp_path)


# ---------------------------------------------------------------- the second corpus (issue 30)
import make_fuzz  # noqa: E402

sys.path.insert(0, str(ROOT / "benchmarks"))
import fuzz_cli  # noqa: E402

# one or two of each kind: files, arguments, images, databases, URLs, cell files, outputs
FUZZ_REPRESENTATIVE = ["scene-id-ansi", "scene-id-lone-surrogate", "scene-shelf-1e300", "scene-size-1e-12",
                       "scene-camera-1e300-away", "plan-safe-risk-1", "camera-width-30000",
                       "image-rgb-png-30000x30000", "image-depth-npy-100000-square", "image-rgb-png-bad-idat",
                       "arg-plan-samples-1e9", "arg-console-samples-1e9", "arg-replay-id-2-70",
                       "url-bracket-open", "url-heartbeat-0", "url-sim-delay-1e308", "cell-symlink-dev-zero",
                       "cell-step-timeout-1e308", "cell-plan-mass-nan", "cell-plan-fifo", "db-replay-plan-not-json", "db-stats-detail-deep",
                       "db-replay-rgb-30000", "out-plan-fifo", "out-perceive-overlay-fifo", "out-replay-html-folder"]
FUZZ_SUBPROCESS = ["image-rgb-png-full-1.2gb", "arg-plan-samples-1e9", "cell-symlink-dev-zero", "db-stats-plan-deep"]


@pytest.fixture(scope="module")
def fuzz(tmp_path_factory) -> dict[str, "make_fuzz.FuzzCase"]:
    return {c.name: c for c in make_fuzz.build(tmp_path_factory.mktemp("fuzz"))}


def test_the_second_corpus_has_150_new_cases_of_every_kind(fuzz) -> None:
    kinds = {n.split("-")[0] for n in fuzz}
    assert len(fuzz) >= 150 and kinds == {"scene", "plan", "camera", "image", "arg", "url", "cell", "db", "out"}
    assert not set(fuzz) & set(MANIFEST)
    assert set(FUZZ_REPRESENTATIVE) <= set(fuzz) and set(FUZZ_SUBPROCESS) <= set(fuzz)


@pytest.mark.parametrize("name", FUZZ_REPRESENTATIVE)
def test_fuzz_case_in_process(name: str, fuzz, capsys) -> None:
    case = fuzz[name]
    t0 = time.monotonic()
    try:
        rc = main(list(case.argv))
    except SystemExit as exc:        # an argparse refusal
        rc = int(exc.code or 0)
    seconds = time.monotonic() - t0
    err = capsys.readouterr().err
    assert fuzz_cli.judge(case, rc, err, seconds, 0) == (), (name, rc, err)


@pytest.mark.parametrize("name", FUZZ_SUBPROCESS)
def test_fuzz_case_as_a_subprocess_in_time_and_memory(name: str, fuzz) -> None:
    r = fuzz_cli.run_case(fuzz[name], fuzz_cli.child_env())
    assert r.problems == (), r


@pytest.mark.slow
def test_every_fuzz_case_as_a_subprocess(fuzz) -> None:
    results = [fuzz_cli.run_case(c, fuzz_cli.child_env()) for c in fuzz.values()]
    failed = [r for r in results if r.problems]
    assert len(results) >= 150 and failed == [], fuzz_cli.summary(failed)
