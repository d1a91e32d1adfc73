"""Can the planner build sample worlds of what `make_valid` makes of a noisy camera's faces? (issue 31)

The tuning role's true shelves (`planning.shelves.generate`, seeds 31000-31059, docs/perception.md
"Roles") become perceived-like boxes: depth unknown, a 25 cm placeholder behind the front, every face's
centre (x, z) and size (width, height) moved by a seeded Gaussian of `--sigma` metres. `make_valid`
rests them, and the planner's first `--samples` sample worlds are built (`build_sample`, seed 0, the
prediction config). Prints each refused scene and the count. No image, no held-out shelf.

    .venv/bin/python benchmarks/make_valid_jitter.py --sigma 0.015
"""
from __future__ import annotations

import argparse
import random
import sys
import warnings
from dataclasses import replace
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))


def jittered(scene, sigma: float, rng: random.Random):
    """The scene's boxes as a camera with `sigma` of face error would give them to make_valid."""
    out = []
    for b in scene.boxes:
        front = b.position[1] - b.size[1] / 2
        d = min(0.25, scene.shelf.depth - front)
        pos = (b.position[0] + rng.gauss(0, sigma), front + d / 2, b.position[2] + rng.gauss(0, sigma))
        size = (b.size[0] + rng.gauss(0, sigma), d, b.size[2] + rng.gauss(0, sigma))
        out.append(replace(b, position=pos, size=size, depth_known=False, extra={"perceived": {}}))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sigma", type=float, default=0.015, help="face error, metres (Gaussian sd)")
    ap.add_argument("--reps", type=int, default=2, help="noisy copies of each shelf")
    ap.add_argument("--samples", type=int, default=3)
    a = ap.parse_args(argv)
    from shelfpick.perception.boxes import make_valid
    from shelfpick.perception.errors import SceneError
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.sample_worlds import build_sample
    from shelfpick.planning.shelves import generate

    cfg, refused, n = PhysicsConfig().for_prediction(), 0, 0
    for seed in range(31000, 31060):
        scene = generate("structured" if seed % 2 == 0 else "unstructured", seed)
        for rep in range(a.reps):
            boxes, _ = make_valid(jittered(scene, a.sigma, random.Random(f"{seed}:{rep}")), scene.shelf)
            n += 1
            for i in range(a.samples):
                try:
                    with warnings.catch_warnings():
                        warnings.simplefilter("ignore")
                        build_sample(scene.with_boxes(boxes), 0, i, cfg).sim.close()
                except SceneError as exc:
                    refused += 1
                    print(f"{seed} copy {rep}: {exc}", flush=True)
                    break
    print(f"sigma {a.sigma} m: {refused} of {n} scenes refused (first {a.samples} sample worlds)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
