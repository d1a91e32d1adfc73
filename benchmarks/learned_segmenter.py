"""The learned segmenter against the depth-and-edge rules, on held-out sets only.

Sets (roles fixed in docs/perception.md before this segmenter was trained; its training
renders use seeds >= 30000):
- `renders`: the fresh held-out renders 1000-1049 (`perceive-bench --count 50 --seed 1000`:
  sampled type-box shelves, default camera, printed cardboard);
- `varied`: the varied renders' held-out role 22000-22039 (`sample_varied_scene` +
  `varied_camera`, plain cardboard on even seeds and mixed on odd, varied light), as
  benchmarks/perceive_angles.py renders them;
- `shelves`: the planning shelves 5000-5039 (`planning.shelves.generate`, structured on even
  seeds, 10 boxes, settled) through benchmarks/perceive_plan.py's framing camera (backed off
  until every front face is in view, 1.3-2 m): the captures `perceive` -> `plan` sees; never a
  tuning or training role of either segmenter;
- `rcan`: the RCAN photos' held-out half (`bench.RCAN_HELD_OUT`), through `bench.bench_rcan`;
- `tele`: the telexistence overhead pallet photos (held out entirely), `bench.bench_telexistence`.
Each rendered frame is rendered once and perceived by both segmenters through
`pipeline.perceive` (RGB-D); matched to the true front faces at IoU >= 0.5. Time: wall and
process CPU of `perceive`, and of the segmenter call alone.

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/learned_segmenter.py --out /tmp/lsb
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

ROOT = Path(__file__).resolve().parent.parent


def frame_scores(scene, cap, segmenter, least: int) -> dict:
    """One capture through `perceive` with `segmenter`: counts, IoUs and times."""
    from shelfpick.perception.evaluation.bench import match
    from shelfpick.perception.evaluation.truth import front_face_masks
    from shelfpick.perception.pipeline import perceive

    gt_ids = [k for k, m in front_face_masks(scene, cap).items() if m.sum() >= least]
    gt_all = front_face_masks(scene, cap)
    gt = [gt_all[k] for k in gt_ids]
    t, c = time.perf_counter(), time.process_time()
    res = perceive(cap, segmenter, scene.shelf)
    sec, cpu = time.perf_counter() - t, time.process_time() - c
    preds = [res.masks == b.mask_label for b in res.scene.boxes]
    pairs = match(preds, gt)
    err = [(float(np.linalg.norm(np.subtract(scene.box(gt_ids[i]).front_center, res.scene.boxes[j].front_center))),
            abs(res.scene.boxes[j].size[0] - scene.box(gt_ids[i]).size[0]),
            abs(res.scene.boxes[j].size[2] - scene.box(gt_ids[i]).size[2])) for i, j, _ in pairs]
    return {"true": len(gt), "pred": len(preds), "matched": len(pairs), "ious": [v for _, _, v in pairs], "err": err,
            "seconds": sec, "cpu": cpu, "segment_seconds": res.timing.get("segment", 0.0)}


def pool(frames: list[dict]) -> dict:
    nt, npd, nm = (sum(f[k] for f in frames) for k in ("true", "pred", "matched"))
    med = (lambda k: float(np.median([f[k] for f in frames])) if frames else None)
    ious = [v for f in frames for v in f["ious"]]
    return {"frames": len(frames), "true": nt, "pred": npd, "matched": nm,
            "recall": nm / nt if nt else None, "precision": nm / npd if npd else None,
            "mean_iou": float(np.mean(ious)) if ious else None, "seconds_median": med("seconds"),
            "centre_err_median_m": float(np.median([e[0] for f in frames for e in f["err"]])) if ious else None,
            "width_err_median_m": float(np.median([e[1] for f in frames for e in f["err"]])) if ious else None,
            "height_err_median_m": float(np.median([e[2] for f in frames for e in f["err"]])) if ious else None,
            "cpu_median": med("cpu"), "segment_seconds_median": med("segment_seconds"),
            "seconds_max": float(np.max([f["seconds"] for f in frames])) if frames else None}


def rendered_set(name: str, seeds: list[int], segmenters: dict, progress: bool = True) -> dict:
    """Both segmenters on each frame of a rendered set."""
    from shelfpick.perception.evaluation.bench import MIN_GT_PIXELS, min_gt_pixels
    from shelfpick.perception.evaluation.scenes import sample_scene, sample_varied_scene, varied_camera
    from shelfpick.perception.render import render

    out: dict[str, list[dict]] = {k: [] for k in segmenters}
    for i, s in enumerate(seeds):
        if name == "varied":
            scene, cam = sample_varied_scene(s), varied_camera(s)
            cap = render(scene, cam, seed=s, looks="plain" if s % 2 == 0 else "mixed", varied_light=True)
            least = min_gt_pixels(cam)
        elif name == "shelves":
            from benchmarks.perceive_plan import framing_camera
            from shelfpick.planning.shelves import generate

            scene = generate("structured" if s % 2 == 0 else "unstructured", s, 10)
            cam = framing_camera(scene)
            cap, least = render(scene, cam, seed=s), min_gt_pixels(cam)
        else:
            scene = sample_scene(s, "structured" if i % 2 == 0 else "unstructured", 10)
            cap, least = render(scene, None, seed=s), MIN_GT_PIXELS
        for k, seg in segmenters.items():
            out[k].append(frame_scores(scene, cap, seg, least))
        if progress:
            print(f"{name} {s}: " + ", ".join(f"{k} {f[-1]['matched']}/{f[-1]['true']} ({f[-1]['pred']} masks)"
                                              for k, f in out.items()), flush=True)
    return {k: pool(v) for k, v in out.items()}


def photo_set(root: Path, segmenters: dict, which: str) -> dict:
    """Photos without depth (RCAN held-out half, or telexistence) through `bench_photos`."""
    from shelfpick.perception.evaluation.bench import RCAN_HELD_OUT, bench_rcan, bench_telexistence

    out = {}
    for k, seg in segmenters.items():
        r = bench_rcan(root, seg, progress=False, names=RCAN_HELD_OUT) if which == "rcan" \
            else bench_telexistence(root, seg, progress=False)
        out[k] = {kk: v for kk, v in r.items() if kk != "rows"}
        out[k]["per_image"] = [(x["image"], x["matched"], x["cartons"], x["predicted"]) for x in r["rows"]]
    return out


def tune(segmenter, realdata: Path, widths: list[int], thresholds: list[float],
         full_res: tuple[bool, ...] = (True,), snaps: tuple[float, ...] = (0.0,)) -> list[dict]:
    """The learned segmenter's input width and interior threshold, scored on the TUNING roles
    only: varied renders 20000-20019 (through `perceive`) and the RCAN tune half (photos)."""
    import dataclasses

    from shelfpick.perception.evaluation.bench import RCAN_TUNE, bench_rcan, min_gt_pixels
    from shelfpick.perception.evaluation.scenes import sample_varied_scene, varied_camera
    from shelfpick.perception.render import render

    frames = []
    for s in range(20000, 20020):
        scene, cam = sample_varied_scene(s), varied_camera(s)
        frames.append((scene, render(scene, cam, seed=s, looks="plain" if s % 2 == 0 else "mixed",
                                     varied_light=True), min_gt_pixels(cam)))
    rows = []
    for w, t, fr, sn in ((w, t, fr, sn) for w in widths for t in thresholds for fr in full_res for sn in snaps):
        seg = segmenter.with_config(dataclasses.replace(segmenter.config, input_width=w, interior_threshold=t,
                                                        full_res=fr, snap_iou=sn))
        r = pool([frame_scores(sc, cap, seg, least) for sc, cap, least in frames])
        p = bench_rcan(realdata / "RCAN_scd_samples" / "back", seg, progress=False, names=RCAN_TUNE)
        rows.append({"input_width": w, "interior_threshold": t, "full_res": fr, "snap_iou": sn,
                     "varied_recall": r["recall"],
                     "varied_centre_err_cm": round(r["centre_err_median_m"] * 100, 3),
                     "varied_precision": r["precision"], "rcan_recall": p["recall"],
                     "rcan_precision": p["precision"], "segment_s": r["segment_seconds_median"]})
        print(json.dumps(rows[-1]), flush=True)
    return rows


def markdown(report: dict) -> str:
    def f(v, d=3):
        return "-" if v is None else f"{v:.{d}f}"

    def cm(s):
        keys = ("centre_err_median_m", "width_err_median_m", "height_err_median_m")
        return " / ".join(f(s[k] * 100, 2) for k in keys) if s.get(keys[0]) is not None else "-"

    head = ("| set | segmenter | faces | recall | precision | mean IoU | centre / width / height err (cm) | "
            "s/frame wall (median) | CPU s | segmenter s |")
    lines = [head, "|---|---|---|---|---|---|---|---|---|---|"]
    for name, by in report["sets"].items():
        for k, s in by.items():
            faces = s.get("true", s.get("cartons"))
            lines.append(f"| {name} | {k} | {faces} | {f(s['recall'])} | {f(s['precision'])} | "
                         f"{f(s.get('mean_iou', s.get('mean_iou_matched')))} | {cm(s)} | "
                         f"{f(s.get('seconds_median', s.get('seconds_per_frame_median')), 2)} | "
                         f"{f(s.get('cpu_median'), 2)} | {f(s.get('segment_seconds_median'), 2)} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sets", default="renders,varied,rcan,tele",
                   help="comma list of renders, varied, shelves, rcan, tele")
    p.add_argument("--weights", default=None, help="learned checkpoint (default: the shipped one)")
    p.add_argument("--count", type=int, default=0, help="first N frames of each rendered set only (0: all)")
    p.add_argument("--realdata", default=str(ROOT.parent / "shared" / "realdata"))
    p.add_argument("--threads", type=int, default=1, help="torch threads for the learned segmenter")
    p.add_argument("--out", default="learned-bench")
    p.add_argument("--tune", action="store_true",
                   help="only sweep input width x interior threshold on the tuning roles (varied 20000-20019, RCAN tune half)")
    p.add_argument("--widths", default="384,480,576", help="--tune: input widths")
    p.add_argument("--thresholds", default="0.4,0.5,0.6", help="--tune: interior thresholds")
    p.add_argument("--snaps", default="0", help="--tune: snap_iou values (0: off)")
    p.add_argument("--full-res-both", action="store_true", help="--tune: maps at 1/4 size and upsampled")
    p.add_argument("--ungated", action="store_true",
                   help="also the learned segmenter without its depth gate (LearnedConfig.depth_gate off)")
    a = p.parse_args(argv)
    import torch

    from shelfpick.perception.segment import load_segmenter

    torch.set_num_threads(a.threads)
    if a.tune:
        rows = tune(load_segmenter(a.weights, "learned"), Path(a.realdata), [int(v) for v in a.widths.split(",")],
                    [float(v) for v in a.thresholds.split(",")], (False, True) if a.full_res_both else (True,),
                    tuple(float(v) for v in a.snaps.split(",")))
        Path(a.out).mkdir(parents=True, exist_ok=True)
        (Path(a.out) / "tune.json").write_text(json.dumps(rows, indent=1), encoding="utf-8")
        return 0
    segs = {"rules": load_segmenter(None, "depth"), "learned": load_segmenter(a.weights, "learned").with_threads(a.threads)}
    if a.ungated:
        import dataclasses

        segs["learned-ungated"] = segs["learned"].with_config(dataclasses.replace(segs["learned"].config,
                                                                                  depth_gate=False))
    report: dict = {"weights": a.weights or "static/weights/shelfpick-learned.pt", "threads": a.threads, "sets": {}}
    wanted = a.sets.split(",")
    if "renders" in wanted:
        seeds = list(range(1000, 1050))[: a.count or None]
        report["sets"]["held-out renders 1000-1049"] = rendered_set("renders", seeds, segs)
    if "varied" in wanted:
        seeds = list(range(22000, 22040))[: a.count or None]
        report["sets"]["varied held out 22000-22039"] = rendered_set("varied", seeds, segs)
    if "shelves" in wanted:
        seeds = list(range(5000, 5040))[: a.count or None]
        report["sets"]["planning shelves 5000-5039, framing camera"] = rendered_set("shelves", seeds, segs)
    if "rcan" in wanted:
        report["sets"]["RCAN held-out half"] = photo_set(Path(a.realdata) / "RCAN_scd_samples" / "back", segs, "rcan")
    if "tele" in wanted:
        report["sets"]["telexistence (held out)"] = photo_set(Path(a.realdata) / "telexistence_box_detection",
                                                             segs, "tele")
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "report.json").write_text(json.dumps(report, indent=1), encoding="utf-8")
    md = markdown(report)
    (out / "report.md").write_text(md, encoding="utf-8")
    print(md)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
