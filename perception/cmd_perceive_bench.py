"""`shelfpick perceive-bench`: perception accuracy on rendered scenes and real captures."""
from __future__ import annotations

import argparse
from pathlib import Path

from shelfpick.perception.errors import PerceptionError

HELP = "measure perception (recall, precision, centre/size/angle error, time) on renders and real data"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenes", help="folder of scene JSON files to render (default: sample --count)")
    p.add_argument("--count", type=int, default=10, help="sampled scenes when no --scenes (half structured)")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the sampled scenes and of the renders' looks and noise (default 0)")
    p.add_argument("--realdata", help="path of shared/realdata (default ../shared/realdata if present)")
    p.add_argument("--no-real", action="store_true", help="rendered scenes only")
    p.add_argument("--no-rendered", action="store_true", help="real captures only")
    p.add_argument("--distance", type=float, default=None,
                   help="render from the default camera moved back to this many m from the shelf front "
                        "(re-pitched to the same aim point; default 1.05)")
    p.add_argument("--segmenter", choices=("auto", "depth", "photo", "yolo", "learned"), default="auto",
                   help="auto: the learned segmenter for RGB-D and photos (the depth-and-edge rules "
                        "where its weights or torch are missing)")
    p.add_argument("--weights", help="YOLO11n-seg weights for --segmenter yolo/auto")
    p.add_argument("--out", default="perceive-bench", help="folder for report.md and report.json")


def run(args: argparse.Namespace) -> int:
    from shelfpick.perception.evaluation import bench
    from shelfpick.perception.scene import write_json
    from shelfpick.perception.segment import load_segmenter, segmenter_name

    if args.count < 1:
        raise PerceptionError(f"--count must be >= 1, got {args.count}")
    if args.scenes and not Path(args.scenes).is_dir():
        raise PerceptionError(f"{args.scenes}: scene folder not found")
    kind = "yolo" if args.weights and args.segmenter == "auto" else args.segmenter
    seg = load_segmenter(args.weights, kind)
    report: dict = {"segmenter": segmenter_name(seg), "skipped": {}}
    if not args.no_rendered:
        scenes = bench.scenes_from(args.scenes, args.count, args.seed)
        if not scenes:
            raise PerceptionError(f"{args.scenes}: no scene JSON files in the folder")
        camera = bench.camera_at(args.distance) if args.distance is not None else None
        from shelfpick.perception.cmd_render import c_stdout_to_stderr

        with c_stdout_to_stderr(keep_stderr=True):   # the renderer's pybullet prints argv[0]= on connect
            summary, frames = bench.bench_rendered(scenes, args.seed, seg, camera=camera)
        if args.distance is not None:
            report["camera_distance_m"] = args.distance
        report["rendered"] = summary
        report["rendered_frames"] = [vars(f) for f in frames]
    if not args.no_real:
        root = Path(args.realdata) if args.realdata else Path(__file__).resolve().parent.parent.parent / "shared" / "realdata"
        if not root.is_dir():
            report["skipped"]["real data"] = f"{root} not found"
        else:
            rcan = root / "RCAN_scd_samples" / "back"
            if rcan.is_dir():
                report["rcan"] = bench.bench_rcan(rcan, seg)
            else:
                report["skipped"]["RCAN_scd_samples"] = f"{rcan} not found"
            tele = root / "telexistence_box_detection"
            if (tele / "Data").is_dir():
                report["telexistence"] = bench.bench_telexistence(tele, seg)
            else:
                report["skipped"]["telexistence_box_detection"] = f"{tele / 'Data'} not found"
            neura = root / "neura_smart_palletizer"
            if neura.is_dir():
                report["neura"] = bench.bench_neura(neura, seg)
            else:
                report["skipped"]["neura_smart_palletizer"] = f"{neura} not found"
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_json(out / "report.json", report)
    md = bench.markdown(report)
    (out / "report.md").write_text(md, encoding="utf-8")
    print(md)
    return 0
