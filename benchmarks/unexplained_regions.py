"""Unexplained matter on generated frames (issue 31 item 2): noise that must not be reported, and
boxes missing from the scene that must be.

For every frame of a role (docs/perception.md, "Roles"):
- `exact`: the true boxes as the camera gives them (front faces exact, depths hidden): every
  region reported is a false alarm (flying pixels, holes, the shelf's boards);
- `less one`: the same, less the visible box with most pixels: is there one region where it stands
  (its front centre inside the region's seen bounds grown by 3 cm)?
- with `--perceive`: `shelfpick perceive`'s scene (the default segmenter): its regions, and for each
  visible true box no perceived face matches (front centre within 5 cm), whether a region covers it.

    .venv/bin/python -m benchmarks.unexplained_regions --role tune
    .venv/bin/python -m benchmarks.unexplained_regions --role held-out --perceive
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from shelfpick.perception.scene import Box, Camera, Scene, Unexplained

JUDGE = Path(__file__).resolve().parents[2] / "shared" / "judge" / "scenes"
NEAR = 0.03      # m a box's front centre may lie outside a region's seen bounds and still be covered
MATCH = 0.05     # m between a perceived and a true front centre: the same box


def frames(role: str):
    """(name, look, truth scene) of every frame of a role, in a fixed order."""
    if role == "tune":
        from shelfpick.planning.shelves import generate

        for seed in range(31000, 31020):
            yield f"{seed}", "flat", generate("structured" if seed % 2 == 0 else "unstructured", seed)
    else:
        for path in sorted(JUDGE.glob("*.json")):
            scene = Scene.load(path)
            for look in ("printed", "stereo"):
                yield path.stem, look, scene


def covers(u: Unexplained, b: Box, near: float = NEAR) -> bool:
    x, _, z = b.front_center
    return u.min[0] - near <= x <= u.max[0] + near and u.min[2] - near <= z <= u.max[2] + near


def one(name: str, look: str, truth: Scene, perceive_too: bool) -> dict:
    from benchmarks.generators import make_frame
    from shelfpick.perception.unexplained import find_unexplained

    f = make_frame(truth.to_json(), look, 0, name)
    cam = Camera.from_json(f.cam.json(0.001))
    seen = truth.hide_depths(0.25)
    exact = find_unexplained(f.depth, cam, truth.shelf, seen.boxes).regions
    px = {bid: int((f.masks == k).sum()) for k, bid in f.labels.items()}
    gone = max(px, key=px.get)
    less = find_unexplained(f.depth, cam, truth.shelf, seen.without([gone]).boxes).regions
    row = {"frame": name, "look": look, "boxes": len(truth.boxes),
           "exact_regions": len(exact), "exact_area_m2": round(sum(u.area_m2 for u in exact), 4),
           "less_one": gone, "less_one_regions": len(less),
           "less_one_found": sum(covers(u, truth.box(gone)) for u in less) == 1}
    if perceive_too:
        row.update(_perceived(f, cam, truth, px))
    return row


def _perceived(f, cam: Camera, truth: Scene, px: dict) -> dict:
    from shelfpick.perception.capture import Capture
    from shelfpick.perception.pipeline import perceive

    t = time.perf_counter()
    res = perceive(Capture(f.rgb, f.depth, cam), None, truth.shelf)
    regions = res.scene.unexplained or ()
    missed = [b for b in truth.boxes if px.get(b.id, 0) > 0 and not any(
        np.linalg.norm(np.subtract(p.front_center, b.front_center)) < MATCH for p in res.scene.boxes)]
    covered = [b.id for b in missed if any(covers(u, b) for u in regions)]
    return {"perceived": len(res.scene.boxes), "perceived_regions": len(regions),
            "missed": [b.id for b in missed], "missed_covered": covered,
            "unexplained_s": round(res.timing.get("unexplained", 0.0), 4),
            "perceive_s": round(time.perf_counter() - t, 3)}


def summary(rows: list[dict]) -> dict:
    out: dict = {}
    for look in sorted({r["look"] for r in rows}):
        rs = [r for r in rows if r["look"] == look]
        s = {"frames": len(rs), "frames_with_a_false_region": sum(r["exact_regions"] > 0 for r in rs),
             "false_regions": sum(r["exact_regions"] for r in rs),
             "missing_box_found": sum(r["less_one_found"] for r in rs),
             "missing_box_extra_regions": sum(r["less_one_regions"] - r["less_one_found"] for r in rs)}
        if "perceived" in rs[0]:
            s.update({"regions_in_perceived_scenes": sum(r["perceived_regions"] for r in rs),
                      "missed_boxes": sum(len(r["missed"]) for r in rs),
                      "missed_boxes_covered": sum(len(r["missed_covered"]) for r in rs),
                      "unexplained_s_p50": float(np.median([r["unexplained_s"] for r in rs]))})
        out[look] = s
    return out


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--role", choices=("tune", "held-out"), default="tune")
    p.add_argument("--perceive", action="store_true", help="also perceive each frame (slow)")
    p.add_argument("--limit", type=int, default=0, help="only the first N frames")
    p.add_argument("--out", help="JSON of every row and the summary")
    a = p.parse_args(argv)
    rows = []
    for i, (name, look, truth) in enumerate(frames(a.role)):
        if a.limit and i >= a.limit:
            break
        rows.append(one(name, look, truth, a.perceive))
        print(json.dumps(rows[-1]), flush=True)
    s = summary(rows)
    print(json.dumps(s, indent=1))
    if a.out:
        Path(a.out).write_text(json.dumps({"rows": rows, "summary": s}, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
