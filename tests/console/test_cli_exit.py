"""The `shelfpick` process's exit: a `perceive` process spares the interpreter's last full garbage
collection (gc.freeze, console/cli.py `_ending_process`); a caller of main() that goes on (a test, a
script) is never touched."""
from __future__ import annotations

import gc
import sys

from shelfpick.console import cli


def _perceive_args(tmp_path) -> list[str]:
    missing = str(tmp_path / "missing.png")
    return ["perceive", "--rgb", missing, "--camera", str(tmp_path / "camera.json"), "--out", str(tmp_path / "s.json")]


def test_a_perceive_process_freezes_what_it_made_before_it_exits(tmp_path, monkeypatch, capsys):
    frozen = []
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(True))
    monkeypatch.setattr(sys, "argv", ["shelfpick"] + _perceive_args(tmp_path))
    assert cli.main() == cli.EXIT_USAGE                     # the process's own command line (the script's call)
    assert frozen == [True]
    err = capsys.readouterr().err
    assert "camera.json: file not found" in err and len(err.splitlines()) == 1     # the error still said, in one line


def test_a_caller_of_main_that_goes_on_and_other_commands_are_left_alone(tmp_path, monkeypatch):
    frozen = []
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(True))
    assert cli.main(_perceive_args(tmp_path)) == cli.EXIT_USAGE     # argv given: a test or a script
    monkeypatch.setattr(sys, "argv", ["shelfpick", "plan", str(tmp_path / "none.json")])
    assert cli.main() == cli.EXIT_USAGE
    assert frozen == []
