"""The learned segmenter on ONNX Runtime (what the console runs) against the torch checkpoint it
was exported from: the same masks? how fast?

On held-out frames only (roles fixed in docs/perception.md; training renders use seeds >= 30000):
- `renders`: the held-out renders 1000-1049 (sampled shelves, default camera), read as RGB-D (the
  segmenter bound to the camera and shelf: depth gate, snap, split, unseen faces);
- `varied`: the varied renders' held-out role 22000-22039 (varied camera, looks and light), RGB-D;
- `rcan`: the RCAN photos' held-out half (`bench.RCAN_HELD_OUT`, ../shared/realdata), read as
  photos (`rgb_only`: two input widths and mirror averaging), at most 960 px a side as `bench` reads them.
Each frame is segmented by both (one thread each, the segmenter's default); every torch mask is
paired with the ONNX mask it overlaps most, one to one (IoU; a torch mask left without one: 0).
Reported: frames, masks, frames whose mask counts differ, min / median IoU, and the median ms per
frame of `segment` and of the network pass alone (`probabilities`), for both; the installed size of
each runtime's packages and of both weight files.

    OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/onnx_segmenter.py --out docs/results/onnx-segmenter.md
    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/onnx_segmenter.py --sets renders --count 5   # a quick look
"""
from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def installed_mib(*modules: str) -> float:
    """du of the packages' folders (as imported here), MiB."""
    total = 0
    for m in modules:
        spec = importlib.util.find_spec(m)
        if spec is None or not spec.submodule_search_locations:
            continue
        out = subprocess.run(["du", "-sk", *spec.submodule_search_locations], capture_output=True, text=True)
        total += sum(int(line.split()[0]) for line in out.stdout.splitlines())
    return total / 1024


def paired_ious(want: list[np.ndarray], got: list[np.ndarray]) -> list[float]:
    """For each mask of `want`, the IoU of the `got` mask paired with it: pairs taken greedily by
    IoU, highest first, one to one; a `want` mask left unpaired scores 0."""
    from shelfpick.perception.evaluation.bench import mask_iou

    cands = sorted(((mask_iou(a, b), i, j) for i, a in enumerate(want) for j, b in enumerate(got)), reverse=True)
    out, used_i, used_j = [0.0] * len(want), set(), set()
    for v, i, j in cands:
        if v > 0 and i not in used_i and j not in used_j:
            out[i] = v
            used_i.add(i)
            used_j.add(j)
    return out


def frames(name: str, count: int, realdata: Path):
    """(label, rgb, depth or None, camera, shelf) of each held-out frame of set `name`."""
    if name == "rcan":
        import cv2

        from shelfpick.perception.evaluation.bench import RCAN_HELD_OUT
        from shelfpick.perception.capture import read_rgb

        for n in RCAN_HELD_OUT[: count or None]:
            rgb = read_rgb(realdata / "RCAN_scd_samples" / "back" / "img" / n)
            s = min(1.0, 960 / max(rgb.shape[:2]))
            if s < 1.0:
                rgb = cv2.resize(rgb, (int(rgb.shape[1] * s), int(rgb.shape[0] * s)), interpolation=cv2.INTER_AREA)
            yield n, rgb, None, None, None
        return
    from shelfpick.perception.evaluation.scenes import sample_scene, sample_varied_scene, varied_camera
    from shelfpick.perception.render import render

    seeds = range(1000, 1050) if name == "renders" else range(22000, 22040)
    for i, s in enumerate(list(seeds)[: count or None]):
        if name == "varied":
            scene, cam = sample_varied_scene(s), varied_camera(s)
            cap = render(scene, cam, seed=s, looks="plain" if s % 2 == 0 else "mixed", varied_light=True)
        else:
            scene = sample_scene(s, "structured" if i % 2 == 0 else "unstructured", 10)
            cap = render(scene, None, seed=s)
        yield str(s), cap.rgb, cap.depth, cap.camera, scene.shelf


def timed(fn):
    t = time.perf_counter()
    out = fn()
    return out, (time.perf_counter() - t) * 1000


def measure_set(name: str, count: int, realdata: Path, onnx_seg, torch_seg) -> dict:
    """Both segmenters on every frame of one set."""
    ious, differ, n_frames, n_masks = [], [], 0, [0, 0]
    ms = {"torch": [], "onnx": [], "torch_net": [], "onnx_net": []}
    for label, rgb, depth, camera, shelf in frames(name, count, realdata):
        segs = {}
        for k, seg in (("torch", torch_seg), ("onnx", onnx_seg)):
            segs[k] = seg.bind(camera, shelf) if depth is not None else seg.rgb_only()
            _, t_net = timed(lambda s=segs[k]: s.probabilities(rgb))
            ms[k + "_net"].append(t_net)
        want, t_torch = timed(lambda: segs["torch"].segment(rgb, depth))
        got, t_onnx = timed(lambda: segs["onnx"].segment(rgb, depth))
        ms["torch"].append(t_torch)
        ms["onnx"].append(t_onnx)
        frame_ious = paired_ious(want, got)
        ious += frame_ious
        n_frames += 1
        n_masks[0] += len(want)
        n_masks[1] += len(got)
        if len(want) != len(got):
            differ.append(label)
        print(f"{name} {label}: {len(want)} torch / {len(got)} onnx masks, min IoU "
              f"{min(frame_ious, default=1.0):.4f}, {t_torch:.0f} / {t_onnx:.0f} ms", flush=True)
    return {"frames": n_frames, "torch_masks": n_masks[0], "onnx_masks": n_masks[1], "differ": differ,
            "min_iou": min(ious, default=None), "median_iou": statistics.median(ious) if ious else None,
            "below_099": sum(v < 0.99 for v in ious), **{k: statistics.median(v) for k, v in ms.items() if v}}


SET_NAMES = {"renders": "held-out renders 1000-1049 (RGB-D)", "varied": "varied held out 22000-22039 (RGB-D)",
             "rcan": "RCAN held-out half (photos)"}


def report(args: argparse.Namespace, rows: dict, versions: dict) -> str:
    """The markdown of docs/results/onnx-segmenter.md."""
    from shelfpick.perception.segment_learned import LEARNED_ONNX, LEARNED_WEIGHTS

    cmd = "OMP_NUM_THREADS=1 python benchmarks/onnx_segmenter.py " + " ".join(sys.argv[1:])
    lines = ["# The learned segmenter on ONNX Runtime vs torch", "",
             f"`{cmd.strip()}` (Python {sys.version.split()[0]}, torch {versions['torch']}, onnxruntime "
             f"{versions['onnxruntime']}, one thread each, {time.strftime('%Y-%m-%d')})", "",
             "Every torch mask paired one to one with the ONNX mask it overlaps most (IoU; none: 0). "
             "ms: median per frame, `segment` (network, instances, and on RGB-D the depth gate and snap, "
             "the same code for both) and the network pass alone (`probabilities`).", "",
             "| set | frames | masks torch / onnx | frames whose counts differ | IoU min | IoU median "
             "| masks < 0.99 | segment ms torch / onnx | network ms torch / onnx |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for name, r in rows.items():
        lines.append(f"| {SET_NAMES[name]} | {r['frames']} | {r['torch_masks']} / {r['onnx_masks']} | "
                     f"{len(r['differ'])} | {r['min_iou']:.4f} | {r['median_iou']:.4f} | {r['below_099']} | "
                     f"{r['torch']:.0f} / {r['onnx']:.0f} | {r['torch_net']:.0f} / {r['onnx_net']:.0f} |")
    lines += ["", "| | torch | ONNX Runtime |", "|---|---:|---:|",
              f"| weights file MiB | {LEARNED_WEIGHTS.stat().st_size / 2**20:.1f} (`{LEARNED_WEIGHTS.name}`, float16) "
              f"| {LEARNED_ONNX.stat().st_size / 2**20:.1f} (`{LEARNED_ONNX.name}`, float32) |",
              f"| installed packages MiB | {installed_mib('torch', 'torchvision', 'ultralytics'):.0f} "
              f"(torch, torchvision, ultralytics) | {installed_mib('onnxruntime'):.0f} (onnxruntime) |", "",
              "Installed sizes are the packages' own folders; torch from PyPI also pulls its CUDA libraries "
              "(nvidia-*, triton): the venvs' totals are in [install-footprint.md](install-footprint.md). "
              "The ONNX file is exported from the checkpoint by `python -m shelfpick.perception.training.onnx_export`."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--sets", default="renders,varied,rcan", help="comma list of renders, varied, rcan")
    p.add_argument("--count", type=int, default=0, help="first N frames of each set only (0: all)")
    p.add_argument("--realdata", default=str(ROOT.parent / "shared" / "realdata"))
    p.add_argument("--out", help="also write the markdown here")
    a = p.parse_args(argv)
    import onnxruntime
    import torch

    from shelfpick.perception.segment_learned import LEARNED_ONNX, LEARNED_WEIGHTS, LearnedSegmenter

    onnx_seg, torch_seg = LearnedSegmenter(LEARNED_ONNX, threads=1), LearnedSegmenter(LEARNED_WEIGHTS, threads=1)
    warm = np.random.default_rng(0).integers(0, 256, (360, 480, 3), dtype=np.uint8)
    for seg in (onnx_seg, torch_seg):          # first passes allocate: not a frame's time
        seg.probabilities(warm)
    rows = {name: measure_set(name, a.count, Path(a.realdata), onnx_seg, torch_seg) for name in a.sets.split(",")}
    md = report(a, rows, {"torch": torch.__version__, "onnxruntime": onnxruntime.__version__})
    print(md)
    if a.out:
        Path(a.out).write_text(md, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
