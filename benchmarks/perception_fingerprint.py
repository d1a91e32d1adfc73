"""A fingerprint of perception's output on a fixed list of frames, to show a refactoring changed nothing.

Per frame: a hash of the final label image, of the scene JSON and of the measured faces, the
notes (`Perception.adjustments`) and warnings, and, for the box catalogue alone, a hash of the
masks it was given and of the masks and notes it returned (so a change upstream of the
catalogue, e.g. in the segmenter, shows as a different input hash, not as a catalogue change).
Two runs are identical when their `frames` agree; timing is reported apart.

Frames (`--quick`: the first 20 and 10 of the first two sets): `perception.evaluation.scenes.sample_scene`
seeds 1000-1049 rendered as `perceive-bench --count 50 --seed 1000` does; the varied renders
20000-20019 and 21000-21019 (tuning and check roles, as benchmarks/perceive_angles.py renders
them; never the held-out set); the planning shelves where the round-11 rules were found
(`planning.shelves.generate("unstructured", seed, 10)` seen by perceive_plan's framing camera,
seeds 5000-5039); the neura pallet RGB-D capture from ../shared/realdata with and without the
default catalogue (if present).

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python -m benchmarks.perception_fingerprint --out /tmp/fp.json
    .venv/bin/python -m benchmarks.perception_fingerprint --compare /tmp/fp-before.json /tmp/fp.json

`--save DIR` also saves each frame's catalogue input; `--replay DIR` re-runs only
`apply_catalogue` on saved inputs (a quick check while editing the catalogue).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import pickle
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
REALDATA = ROOT.parent / "shared" / "realdata"


def _h(*arrays) -> str:
    d = hashlib.sha256()
    for a in arrays:
        a = np.ascontiguousarray(a)
        d.update(str(a.shape).encode() + str(a.dtype).encode())
        d.update(a.tobytes())
    return d.hexdigest()[:16]


def _hs(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()[:16]


class CatalogueTap:
    """Wraps `perception.pipeline.apply_catalogue` to record what the catalogue got and gave."""

    def __init__(self, save_dir: Path | None = None) -> None:
        import shelfpick.perception.pipeline as pl

        self.pl, self.inner = pl, pl.apply_catalogue
        self.save_dir, self.name, self.calls, self.seconds = save_dir, "", [], 0.0
        pl.apply_catalogue = self

    def __call__(self, masks, depth, camera, rgb, cat):
        if self.save_dir is not None:
            self.save_dir.mkdir(parents=True, exist_ok=True)
            np.savez_compressed(self.save_dir / f"{self.name}-{len(self.calls)}.npz",
                                masks=np.asarray(masks, bool), depth=depth,
                                rgb=rgb if rgb is not None else np.zeros(0, np.uint8),
                                camera=np.frombuffer(pickle.dumps(camera), np.uint8),
                                cat=json.dumps(_cat_json(cat)))
        got = _h(*[np.asarray(m, bool) for m in masks]) if masks else "none"
        t = time.process_time()
        out, faces, mine = self.inner(masks, depth, camera, rgb, cat)
        self.seconds += time.process_time() - t
        self.calls.append({"in": got, "out": _h(*out) if out else "none", "notes": mine,
                           "faces": _hs(json.dumps([None if f is None else f.to_json() for f in faces]))})
        return out, faces, mine

    def close(self) -> None:
        self.pl.apply_catalogue = self.inner


def _cat_json(cat) -> dict:
    from dataclasses import fields

    return {f.name: getattr(cat, f.name) for f in fields(cat) if f.init}


def _frames(quick: bool):
    """(name, capture, shelf, catalogue kwargs) for each frame, rendered lazily."""
    from shelfpick.perception.evaluation.scenes import sample_scene, sample_varied_scene, varied_camera
    from shelfpick.perception.render import render

    for i in range(20 if quick else 50):
        seed = 1000 + i
        kind = "structured" if i % 2 == 0 else "unstructured"
        sc = sample_scene(seed, kind, 10)
        yield f"bench-{seed}", (lambda sc=sc, seed=seed: render(sc, None, seed=seed)), sc.shelf, {}
    varied = list(range(20000, 20010)) + ([] if quick else list(range(20010, 20020)) + list(range(21000, 21020)))
    for seed in varied:
        sc = sample_varied_scene(seed)
        yield f"varied-{seed}", (lambda sc=sc, seed=seed: render(
            sc, varied_camera(seed), seed=seed, looks="plain" if seed % 2 == 0 else "mixed",
            varied_light=True)), sc.shelf, {}
    if quick:
        return
    sys.path.insert(0, str(ROOT / "benchmarks"))
    from benchmarks.perceive_plan import framing_camera
    from shelfpick.planning.shelves import generate

    for seed in range(5000, 5040):
        truth = generate("unstructured", seed, 10)
        yield f"plan-{seed}", (lambda t=truth, seed=seed: render(t, framing_camera(t), seed=seed)), truth.shelf, {}
    neura = REALDATA / "neura_smart_palletizer"
    if neura.is_dir():
        from shelfpick.perception.evaluation.bench import neura_capture
        from shelfpick.perception.pipeline import DEFAULT_CATALOGUE

        cap, shelf, _ = neura_capture(neura)
        yield "neura-nocat", (lambda: cap), shelf, {"catalogue": None}
        yield "neura-cat", (lambda: cap), shelf, {"catalogue": DEFAULT_CATALOGUE}


def fingerprint(quick: bool = False, save: Path | None = None) -> dict:
    from shelfpick.perception.cmd_render import c_stdout_to_stderr
    from shelfpick.perception.pipeline import perceive

    tap = CatalogueTap(save)
    frames, secs, cat_secs = {}, {}, {}
    try:
        for name, make, shelf, kw in _frames(quick):
            with c_stdout_to_stderr():
                cap = make()
            tap.name, tap.calls, tap.seconds = name, [], 0.0
            t = time.process_time()
            res = perceive(cap, None, shelf, **kw)
            secs[name] = time.process_time() - t
            cat_secs[name] = tap.seconds
            frames[name] = {
                "masks": _h(res.masks), "scene": _hs(json.dumps(res.scene.to_json(), sort_keys=True)),
                "faces": _hs(json.dumps([f.to_json() for f in res.faces], sort_keys=True)),
                "boxes": len(res.scene.boxes), "adjustments": list(res.adjustments),
                "warnings": list(res.warnings), "catalogue": tap.calls}
            print(f"{name}: {len(res.scene.boxes)} boxes, {secs[name]:.2f} s CPU "
                  f"(catalogue {cat_secs[name]:.2f} s), masks {frames[name]['masks']}", file=sys.stderr)
    finally:
        tap.close()
    return {"frames": frames, "cpu_seconds": secs, "catalogue_cpu_seconds": cat_secs,
            "cpu_median": float(np.median(list(secs.values()))),
            "catalogue_cpu_total": float(sum(cat_secs.values()))}


def replay(save: Path) -> dict:
    """Re-run only `apply_catalogue` on the saved inputs: {file: (masks hash, notes)}, CPU s."""
    from shelfpick.perception.box_catalogue import Catalogue, apply_catalogue

    out, total = {}, 0.0
    for f in sorted(save.glob("*.npz")):
        z = np.load(f)
        cat = json.loads(str(z["cat"]))
        cat["types"] = tuple(tuple(t) for t in cat["types"])
        rgb = z["rgb"] if z["rgb"].size else None
        camera = pickle.loads(z["camera"].tobytes())   # from_json normalises the quaternion
        t = time.process_time()
        masks, faces, notes = apply_catalogue(list(z["masks"]), z["depth"], camera, rgb, Catalogue(**cat))
        total += time.process_time() - t
        out[f.stem] = {"out": _h(*masks) if masks else "none", "notes": notes,
                       "faces": _hs(json.dumps([None if q is None else q.to_json() for q in faces]))}
    return {"frames": out, "catalogue_cpu_total": total}


def compare(a: dict, b: dict) -> list[str]:
    diffs = []
    for k in sorted(set(a["frames"]) | set(b["frames"])):
        if a["frames"].get(k) != b["frames"].get(k):
            diffs.append(k)
    return diffs


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", help="write the fingerprint JSON here")
    ap.add_argument("--quick", action="store_true", help="only the 30 bench and varied renders")
    ap.add_argument("--save", help="also save each catalogue input as DIR/<frame>-<k>.npz")
    ap.add_argument("--replay", help="re-run apply_catalogue on the inputs saved in DIR")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two fingerprint JSON files")
    args = ap.parse_args(argv)
    if args.compare:
        a, b = (json.loads(Path(p).read_text()) for p in args.compare)
        diffs = compare(a, b)
        print(f"{len(set(a['frames']) & set(b['frames']))} frames in both; "
              f"{'identical' if not diffs else 'DIFFERENT: ' + ', '.join(diffs)}")
        for key in ("cpu_median", "catalogue_cpu_total"):
            if key in a and key in b:
                print(f"{key}: {a[key]:.3f} -> {b[key]:.3f} s")
        return 1 if diffs else 0
    res = replay(Path(args.replay)) if args.replay else \
        fingerprint(args.quick, Path(args.save) if args.save else None)
    text = json.dumps(res, indent=1, sort_keys=True)
    if args.out:
        Path(args.out).write_text(text)
    print(f"{len(res['frames'])} frames; catalogue CPU {res['catalogue_cpu_total']:.2f} s"
          + (f"; perceive CPU median {res['cpu_median']:.2f} s" if "cpu_median" in res else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
