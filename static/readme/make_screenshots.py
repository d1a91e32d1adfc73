"""Regenerate the console's screenshots in README.md and docs/console.md (headless Chromium).

    .venv/bin/python static/readme/make_screenshots.py

Runs the scripted operator session (tests/console/test_operator_session.py: capture, a target
picked in 3D, both plans, the preview of a risky step in a world where it collapses, the hold
after a deviation, `continue`, Stop, replay, HTML export) with SHELFPICK_SHOTS pointing at a
temporary folder, then copies its stages here and to docs/img/:

- static/readme/operator.png: the plans side by side after `Plan extraction` (stage 2);
- static/readme/collapse-preview.png: the heuristic plan's risky step shown in a sample world
  where it collapses (stage 3);
- docs/img/console-NN-STAGE.png: every stage, for docs/console.md.

Look at the pictures before committing them: they are what a new operator reads first.
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = {"02-plans-extraction.png": "operator.png", "03-preview.png": "collapse-preview.png"}


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, SHELFPICK_SHOTS=tmp)
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                               "tests/console/test_operator_session.py"], cwd=ROOT, env=env)
        if done.returncode != 0:
            print("the operator session failed: no screenshots copied", file=sys.stderr)
            return 1
        shots = sorted(Path(tmp).glob("*.png"))
        img = ROOT / "docs" / "img"
        for old in img.glob("console-*.png"):
            old.unlink()
        for p in shots:
            shutil.copy(p, img / f"console-{p.name}")
            if p.name in README:
                shutil.copy(p, ROOT / "static" / "readme" / README[p.name])
        print(f"{len(shots)} stages -> docs/img/console-*.png; {len(README)} -> static/readme/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
