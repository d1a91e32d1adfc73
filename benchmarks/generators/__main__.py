"""`python -m benchmarks.generators --look L --scene S.json --seed N --out DIR`: one capture folder."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from benchmarks.generators import LOOK_NAMES, write_frame


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--look", choices=LOOK_NAMES, required=True)
    ap.add_argument("--scene", required=True, help="shelfpick.scene/1 file (the true shelf)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, help="folder for rgb.png, depth.png, camera.json, masks.*")
    a = ap.parse_args(argv)
    try:
        scene = json.loads(Path(a.scene).read_text(encoding="utf-8"))
        scene["boxes"], scene["shelf"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"generators: {a.scene}: not a readable shelfpick.scene/1 file ({exc})", file=sys.stderr)
        return 2
    write_frame(scene, a.look, a.seed, a.out, Path(a.scene).stem)
    return 0


if __name__ == "__main__":
    sys.exit(main())
