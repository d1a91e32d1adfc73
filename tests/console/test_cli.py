"""The `shelfpick` dispatcher: every subcommand the issues name exists."""
from __future__ import annotations

import subprocess
import sys

from console.cli import COMMANDS, build_parser


def test_all_subcommands_registered():
    parser = build_parser()
    sub = next(a for a in parser._actions if a.dest == "command")
    assert set(sub.choices) == set(COMMANDS)


def test_help_is_fast_and_imports_nothing_heavy():
    code = ("import sys; from console.cli import build_parser; build_parser(); "
            "heavy = [m for m in ('torch', 'pybullet', 'viser', 'ultralytics', 'cv2') if m in sys.modules]; "
            "print(','.join(heavy))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""
