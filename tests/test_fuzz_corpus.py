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

from console.cli import main

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
    p = subprocess.run([sys.executable, "-m", "console.cli", *argv], cwd=ROOT, capture_output=True, text=True,
                       timeout=SECONDS + 20)
    judge(name, p.returncode, p.stderr, time.monotonic() - t0, names)


@pytest.mark.parametrize("name", REPRESENTATIVE)
def test_case_as_a_subprocess(name: str, tmp_path: Path) -> None:
    _subprocess(name, tmp_path)


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(set(MANIFEST) - set(REPRESENTATIVE)))
def test_every_case_as_a_subprocess(name: str, tmp_path: Path) -> None:
    _subprocess(name, tmp_path)
