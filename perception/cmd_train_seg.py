"""`shelfpick train-seg --out W`: train the YOLO11n-seg box segmenter on synthetic renders."""
from __future__ import annotations

import argparse
import logging
import time

log = logging.getLogger(__name__)

HELP = "train the YOLO11n-seg box segmenter on synthetic shelf renders (offline, resumable)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="weights file to write (.pt)")
    parser.add_argument("--images", type=int, default=360, help="rendered images, 15%% for validation (default 360)")
    parser.add_argument("--epochs", type=int, default=25, help="training epochs (default 25)")
    parser.add_argument("--imgsz", type=int, default=320, help="network input size in pixels (default 320)")
    parser.add_argument("--batch", type=int, default=16, help="batch size (default 16)")
    parser.add_argument("--seed", type=int, default=0, help="scenes, looks and training seed (default 0)")
    parser.add_argument("--work", help="work folder for the dataset and checkpoints "
                                       "(default: OUT without .pt + '.work'); re-running resumes there")
    parser.add_argument("--workers", type=int, default=0, help="data loader processes (default 0)")


def run(args: argparse.Namespace) -> int:
    from shelfpick.perception.scene import output_path
    from shelfpick.perception.training.yolo import train

    output_path(args.out, "--out")          # never onto a device, FIFO or folder
    t0 = time.perf_counter()
    res = train(args.out, images=args.images, epochs=args.epochs, imgsz=args.imgsz, seed=args.seed,
                batch=args.batch, work=args.work, workers=args.workers)
    dt = time.perf_counter() - t0
    m = "n/a" if res.map50_95 is None else f"{res.map50_95:.3f}"
    m50 = "n/a" if res.map50 is None else f"{res.map50:.3f}"
    log.info("%s%d epochs on %d images (%d boxes) in %.1f min; validation mask mAP50-95 %s, mAP50 %s -> %s",
             "resumed, " if res.resumed else "", res.epochs, res.dataset.n_train, res.dataset.n_instances,
             dt / 60, m, m50, res.weights)
    return 0
