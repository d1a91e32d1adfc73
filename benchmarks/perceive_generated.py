"""Segmentation figures on the TUNING frames of issue 31 (docs/perception.md, "Roles"): look `flat` of
`benchmarks/generators` on `planning.shelves.generate` shelves, seeds 31000-31019 (even structured, odd
unstructured). Perceived in this process (`perception.pipeline.perceive`, default segmenter); perceived
boxes matched to true ones by front-face position as `camera_to_plan.match_fronts` does.

    .venv/bin/python benchmarks/perceive_generated.py --out /tmp/tune            # figures + per-frame lines
    .venv/bin/python benchmarks/perceive_generated.py --seeds 31004 --out /tmp/tune --keep   # one frame, overlay kept

Prints a line per frame (true fronts, perceived, matched, missed true ids, unmatched perceived ids, warnings)
and the totals. Each perceived scene must also be one the planner can sample: its first `--samples` sample
worlds are built as `planning.sample_worlds.build_sample` builds them (seed 0, the prediction config); a
refusal is printed (REFUSED) and counted (SAMPLEABLE); seeds 31020-31059 are more of the tune role. Held-out looks are refused: they are measured only by camera_to_plan.py.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

TUNE_SEEDS = range(31000, 31060)   # 31020-31059: more of the tune role (issue 31, h10)
DEFAULT_SEEDS = "31000-31019"
TUNE_LOOKS = ("flat", "labels")   # docs/perception.md, "Roles": both tune; printed and stereo are held out


def tune_scene(seed: int, cache: Path) -> dict:
    """The tuning shelf of a seed (settled by planning.shelves.generate), cached as JSON."""
    path = cache / f"shelf_{seed}.json"
    if path.exists():
        return json.loads(path.read_text())
    from shelfpick.planning.shelves import generate

    doc = generate("structured" if seed % 2 == 0 else "unstructured", seed).to_json()
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc))
    return doc


def one_frame(seed: int, look: str, out: Path, keep: bool, samples: int = 3) -> dict:
    """Render, perceive in process, match: the frame's figures."""
    import cv2
    import numpy as np

    from benchmarks.camera_to_plan import VISIBLE_PX, match_fronts, visible_fronts
    from benchmarks.generators import write_frame
    from shelfpick.perception.capture import load_capture
    from shelfpick.perception.pipeline import perceive

    truth = tune_scene(seed, out / "shelves")
    folder = out / look / str(seed)
    paths = write_frame(truth, look, 0, folder, f"tune{seed}")
    cap = load_capture(paths["rgb"], paths["depth"], paths["camera"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t, c = time.perf_counter(), time.process_time()
        res = perceive(cap)
        took, cpu = time.perf_counter() - t, time.process_time() - c
    seen = {k for k, n in visible_fronts(truth, folder).items() if n >= VISIBLE_PX}
    m = match_fronts(res.scene.to_json(), truth)
    if keep:
        cv2.imwrite(str(folder / "overlay.png"), cv2.cvtColor(res.overlay, cv2.COLOR_RGB2BGR))
    matched_true = {t for t, _ in m.values()}
    return {"seed": seed, "true": len(seen), "perceived": len(res.scene.boxes), "matched": len(m),
            "matched_true": len(matched_true & seen), "missed": sorted(seen - matched_true),
            "unmatched": sorted(b.id for b in res.scene.boxes if b.id not in m),
            "err": [d for _, d in m.values()], "s": took, "cpu_s": cpu, "warnings": list(res.warnings),
            "notes": list(res.adjustments), "refused": sample_check(res.scene, samples) if samples else [], "median_cm": 100 * float(np.median([d for _, d in m.values()] or [np.nan]))}


def sample_check(scene, samples: int = 3, seed: int = 0) -> list[str]:
    """Whether the planner can build the sample worlds of a perceived scene (issue 31: the held-out
    stereo plans fell 34 -> 30 on scenes refused with "no draw of sample can be built"): the
    refusals, one line a refused sample (empty: every sample world was built)."""
    from shelfpick.perception.errors import SceneError
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.sample_worlds import build_sample

    config = PhysicsConfig().for_prediction()
    out: list[str] = []
    for i in range(samples):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                build_sample(scene, seed, i, config).sim.close()
        except SceneError as exc:
            out.append(str(exc))
    return out


def tuning_look(look: str) -> str:
    """`look` when it is a tuning look; ValueError naming it otherwise (held-out looks are camera_to_plan's)."""
    if look not in TUNE_LOOKS:
        raise ValueError(f"--look: {look!r} is not a tuning look ({', '.join(TUNE_LOOKS)}); held-out looks "
                         "are measured by camera_to_plan.py only")
    return look


def tuning_seeds(text: str, flag: str = "--seeds") -> list[int]:
    """The tuning shelves of `flag` (a range A-B or a comma list); ValueError naming the flag and the
    value when it is not one or a seed lies outside the tuning role."""
    try:
        if "-" in text:
            lo, hi = (int(x) for x in text.split("-", 1))
            seeds = list(range(lo, hi + 1))
        else:
            seeds = [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise ValueError(f"{flag}: expected A-B or a comma list, got {text!r}") from None
    bad = [s for s in seeds if s not in TUNE_SEEDS]
    if bad or not seeds:
        raise ValueError(f"{flag}: {bad[0] if bad else text!r} is not a tuning shelf "
                         f"(only the tuning seeds {TUNE_SEEDS[0]}-{TUNE_SEEDS[-1]})")
    return seeds


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--look", default="flat")
    ap.add_argument("--seeds", default=DEFAULT_SEEDS, help="a range A-B or a comma list")
    ap.add_argument("--out", required=True)
    ap.add_argument("--keep", action="store_true", help="write each frame's overlay.png")
    ap.add_argument("-v", action="store_true", help="print warnings and notes per frame")
    ap.add_argument("--samples", type=int, default=3,
                    help="sample worlds the planner must be able to build from each perceived scene (0: skip)")
    a = ap.parse_args(argv)
    try:
        tuning_look(a.look)
        seeds = tuning_seeds(a.seeds)
    except ValueError as exc:
        print(f"perceive_generated: {exc}", file=sys.stderr)
        return 2
    rows = []
    for s in seeds:
        r = one_frame(s, a.look, Path(a.out), a.keep, a.samples)
        rows.append(r)
        print(f"{s}: true {r['true']} perceived {r['perceived']} matched {r['matched_true']} "
              f"median {r['median_cm']:.2f} cm, {r['s']:.2f} s; missed {r['missed']} unmatched {r['unmatched']}"
              + "".join(f"\n    REFUSED: {why}" for why in r["refused"]), flush=True)
        if a.v:
            for w in r["warnings"] + r["notes"]:
                print(f"    {w}")
    import numpy as np

    t, p = sum(r["true"] for r in rows), sum(r["perceived"] for r in rows)
    errs = [e for r in rows for e in r["err"]]
    print(f"TOTAL {len(rows)} frames: recall {sum(r['matched_true'] for r in rows) / t:.3f} "
          f"precision {sum(r['matched'] for r in rows) / max(p, 1):.3f} centre median "
          f"{100 * float(np.median(errs)):.2f} cm; perceive p50 {float(np.median([r['s'] for r in rows])):.2f} s wall, "
          f"{float(np.median([r['cpu_s'] for r in rows])):.2f} s CPU (this process)")
    e = 100 * np.asarray(errs or [np.nan])
    print(f"ERRORS {len(errs)} matched fronts: centre error p75 {float(np.percentile(e, 75)):.2f} cm, "
          f"p90 {float(np.percentile(e, 90)):.2f} cm; {int((e > 2).sum())} over 2 cm, {int((e > 4).sum())} over 4 cm")
    if a.samples:
        refused = [r["seed"] for r in rows if r["refused"]]
        print(f"SAMPLEABLE {len(rows) - len(refused)} of {len(rows)} perceived scenes (the first {a.samples} sample "
              f"worlds built); refused: {sum(len(r['refused']) for r in rows)} samples on frames {refused}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
