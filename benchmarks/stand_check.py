"""How many of the judge's shelves, seen with perception error, does the scene check call "cannot stand as seen"?

For each of the independent judge's 40 true shelves, the camera's view (`observe.py` of
../shared/judge, imported at run time, never copied) at `--noise` metres of face error, as the
judge's `evaluate.py` makes it; then the shelf's sample worlds as `shelfpick plan` builds them,
and their `scene_check`. A shelf the judge holds true that we call not standing is a false report
(and every plan on it is declared unsafe).

    .venv/bin/python benchmarks/stand_check.py --noise 0.01
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import warnings
from pathlib import Path
from typing import Sequence

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import init_worker  # noqa: E402


def judge_view(judge_dir: Path, name: str, noise: float) -> dict:
    """The judge's shelf `name` as its camera gives it at `noise` m of face error (`observe.py`,
    imported at run time, never copied; the judge's observation seed for that shelf)."""
    init_worker(str(judge_dir))
    from observe import observed

    truth = json.loads((judge_dir / "scenes" / f"{name}.json").read_text())
    return observed(truth, noise=noise, seed=int(name[1:]) + 17)


def check_shelf(judge_dir: Path, name: str, noise: float, samples: int, work: Path) -> dict:
    """The scene check of shelf `name` seen at `noise` (the judge's observation seed)."""
    from shelfpick.perception.scene import Scene
    from shelfpick.planning.predict import Predictor

    path = work / f"{name}.json"
    path.write_text(json.dumps(judge_view(judge_dir, name, noise)))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        predictor = Predictor(Scene.load(path), samples=samples, seed=0, workers=1)
        try:
            check = predictor.scene_check
        finally:
            predictor.close()
    return {"scene": name, "stands_as_seen": check["stands_as_seen"], "problems": check["problems"]}


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--samples", type=int, default=10)
    ap.add_argument("--judge", default=str(ROOT.parent / "shared" / "judge"))
    a = ap.parse_args(argv)
    judge_dir = Path(a.judge)
    if not (judge_dir / "scenes").is_dir():
        print(f"error: --judge: no scenes folder in {judge_dir}", file=sys.stderr)
        return 2
    init_worker(str(judge_dir))
    names = sorted(p.stem for p in (judge_dir / "scenes").glob("*.json"))
    from tqdm import tqdm
    with tempfile.TemporaryDirectory() as tmp:
        rows = [check_shelf(judge_dir, n, a.noise, a.samples, Path(tmp))
                for n in tqdm(names, desc="shelves", file=sys.stderr)]
    bad = [r for r in rows if not r["stands_as_seen"]]
    for r in bad:
        print(f"  {r['scene']}: " + "; ".join(f"{p['box']} {p['what']}" for p in r["problems"]))
    print(f"noise {a.noise * 100:.1f} cm: {len(bad)} of {len(rows)} shelves called not standing as seen")
    return 0


if __name__ == "__main__":
    sys.exit(main())
