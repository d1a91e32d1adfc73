"""The `shelfpick` dispatcher: every subcommand the issues name exists."""
from __future__ import annotations

import subprocess
import sys

from shelfpick.console.cli import COMMANDS, build_parser


def test_all_subcommands_registered():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) == set(COMMANDS)


def test_help_is_fast_and_imports_nothing_heavy():
    code = ("import sys; from shelfpick.console.cli import build_parser; build_parser(); "
            "heavy = [m for m in ('torch', 'pybullet', 'viser', 'ultralytics', 'cv2') if m in sys.modules]; "
            "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


def test_every_option_of_every_command_has_help():
    import argparse

    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    missing = [f"{name} {'/'.join(a.option_strings) or a.dest}" for name, p in sub.choices.items()
               for a in p._actions if not a.help or a.help == argparse.SUPPRESS]
    assert missing == []


def test_version_prints_the_distribution_version():
    from importlib.metadata import version

    out = subprocess.run([sys.executable, "-m", "shelfpick.console.cli", "--version"], capture_output=True, text=True)
    assert out.returncode == 0 and out.stdout.strip() == f"shelfpick {version('shelfpick')}"


def test_render_writes_nothing_on_stdout_and_quiet_silences_stderr(tmp_path):
    """pybullet's C code printed `argv[0]=` on stdout; status lines are log records on stderr."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    scene = str(root / "static" / "demo" / "demo-small-6.json")
    run = subprocess.run([sys.executable, "-m", "shelfpick.console.cli", "render", scene, "--out", str(tmp_path / "r")],
                         capture_output=True, text=True, cwd=root, timeout=120)
    assert run.returncode == 0 and run.stdout == ""
    assert "shelfpick render: rendered 6 boxes" in run.stderr
    quiet = subprocess.run([sys.executable, "-m", "shelfpick.console.cli", "-q", "render", scene, "--out",
                            str(tmp_path / "q")], capture_output=True, text=True, cwd=root, timeout=120)
    assert quiet.returncode == 0 and quiet.stdout == "" and quiet.stderr == ""   # pybullet's banner too


def test_bad_input_is_one_line_on_stderr_exit_2(tmp_path, capsys):
    from shelfpick.console.cli import main

    (tmp_path / "s.json").write_text('{"format": "shelfpick.scene/1", "shelf": {"width": -1}}')
    assert main(["plan", str(tmp_path / "s.json"), "--target", "b0"]) == 2
    cap = capsys.readouterr()
    assert cap.out == "" and len(cap.err.strip().splitlines()) == 1 and "s.json" in cap.err


def test_verbose_adds_debug_records_and_quiet_keeps_only_warnings(tmp_path, capsys):
    from pathlib import Path

    from shelfpick.console.cli import main

    demo = str(Path(__file__).resolve().parents[2] / "static" / "demo" / "demo-small-6.json")
    argv = ["plan", demo, "--target", "b1", "--samples", "2", "--workers", "1", "--out", str(tmp_path / "p.json")]
    assert main(["-v"] + argv) == 0
    err = capsys.readouterr().err
    assert "shelfpick plan: debug: scene" in err and "step(s)" in err
    assert main(argv + ["-q"]) == 0
    assert "step(s)" not in capsys.readouterr().err


def test_main_puts_the_loggers_back_as_they_were(tmp_path):
    import logging

    from shelfpick.console.cli import LOGGERS, main

    before = [(logging.getLogger(n).level, logging.getLogger(n).propagate, list(logging.getLogger(n).handlers))
              for n in LOGGERS]
    main(["plan", str(tmp_path / "missing.json"), "--target", "b0"])
    after = [(logging.getLogger(n).level, logging.getLogger(n).propagate, list(logging.getLogger(n).handlers))
             for n in LOGGERS]
    assert after == before
