"""Photo inference settings of the learned segmenter on the RCAN tune half only (issue 14).

Why: photos are read at `LearnedConfig.input_width` (480 px), where a wall of 29 cartons leaves
each one a few dozen pixels wide. This sweeps, without retraining, the photo-only settings
(`LearnedConfig.photo_input_widths`: one width or several whose maps are averaged, `photo_flip`)
and the instance thresholds (`photo_interior_threshold`, `foreground_threshold`, `photo_min_seed_px`), through `bench.bench_rcan(..., names=RCAN_TUNE)`:
the same resize to 960 px, `refine` and IoU-0.5 matching as `perceive-bench`. The held-out half
is never read here (the choice is made on the tuning role, docs/perception.md "Held-out
discipline").

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/photo_inference.py --out /tmp/photo_inf
    ... --widths 480,640 --flip yes --scales "480+640" --interior 0.5,0.7 --seed-px 12,24 --cached

`--cached` keeps each photo's probability maps per (width, flip, scales) across threshold
settings (the seconds are then not the photo's time; time a setting without it).
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import itertools
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from shelfpick.perception.evaluation import bench  # noqa: E402
from shelfpick.perception.segment_learned import LearnedSegmenter  # noqa: E402

RCAN = Path(__file__).resolve().parent.parent.parent / "shared" / "realdata" / "RCAN_scd_samples" / "back"


class Cached(LearnedSegmenter):
    """The shipped segmenter, its probability maps kept per photo and setting (threshold sweeps)."""

    cache: dict | None = None

    def probabilities(self, rgb: np.ndarray) -> np.ndarray:
        key = (hashlib.sha1(np.ascontiguousarray(rgb).tobytes()).hexdigest(), self.config.input_width,
               tuple(self.config.input_widths), self.config.flip)
        if self.cache is None:
            return super().probabilities(rgb)
        if key not in self.cache:
            self.cache[key] = super().probabilities(rgb)
        return self.cache[key]


def run(seg: Cached, cfg) -> dict:
    """One photo setting (`cfg`'s photo_* fields) over the tune half."""
    r = bench.bench_rcan(RCAN, seg.with_config(cfg), progress=False, names=bench.RCAN_TUNE)
    assert not {row["image"] for row in r["rows"]} & set(bench.RCAN_HELD_OUT)
    return {"photo_input_widths": list(cfg.photo_input_widths), "photo_flip": cfg.photo_flip,
            "interior_threshold": cfg.photo_interior_threshold, "foreground_threshold": cfg.foreground_threshold,
            "min_seed_px": cfg.photo_min_seed_px, "matched": r["matched"], "predicted": r["predicted"],
            "cartons": r["cartons"], "recall": round(r["recall"], 3), "precision": round(r["precision"], 3),
            "mean_iou": round(r["mean_iou_matched"], 3), "s_median": r["seconds_per_frame_median"],
            "s_max": r["seconds_per_frame_max"], "per_photo": {row["image"]: row["matched"] for row in r["rows"]}}


def floats(s: str) -> list[float]:
    return [float(v) for v in s.split(",") if v]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--widths", default="480,640,800,960")
    p.add_argument("--flip", choices=("no", "yes", "both"), default="both")
    p.add_argument("--scales", default="", help="multi-scale sets, e.g. '640+960;480+800' (each set one run)")
    p.add_argument("--interior", default="0.5")
    p.add_argument("--foreground", default="0.5")
    p.add_argument("--seed-px", default="12")
    p.add_argument("--cached", action="store_true")
    p.add_argument("--out", required=True)
    a = p.parse_args(argv)
    seg = Cached()
    seg.cache = {} if a.cached else None
    flips = {"no": [False], "yes": [True], "both": [False, True]}[a.flip]
    looks = [(int(w),) for w in a.widths.split(",") if w]
    looks += [tuple(int(v) for v in part.split("+")) for part in a.scales.split(";") if part]
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for widths, flip in itertools.product(looks, flips):
        for it, ft, sp in itertools.product(floats(a.interior), floats(a.foreground), floats(a.seed_px)):
            cfg = dataclasses.replace(seg.config, photo_input_widths=widths, photo_flip=flip,
                                      photo_interior_threshold=it, foreground_threshold=ft, photo_min_seed_px=int(sp))
            row = run(seg, cfg)
            rows.append(row)
            print(json.dumps({k: v for k, v in row.items()}), flush=True)
        if seg.cache is not None:
            seg.cache.clear()
    (out / "tune.json").write_text(json.dumps(rows, indent=1), encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
