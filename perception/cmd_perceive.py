"""`shelfpick perceive`: one RGB(-D) capture to a scene, an overlay and instance masks."""
from __future__ import annotations

import argparse
import sys

HELP = "perceive a scene (depth_known false) from an RGB image, a depth image and a camera file"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rgb", required=True, help="colour image (PNG/JPEG)")
    p.add_argument("--depth", help="depth image (uint16 PNG in camera depth_scale units, or .npy)")
    p.add_argument("--camera", required=True, help="shelfpick.camera/1 file (intrinsics + pose)")
    p.add_argument("--weights", help="YOLO11n-seg weights (.pt); implies --segmenter yolo")
    p.add_argument("--segmenter", choices=("auto", "depth", "photo", "yolo"), default="auto",
                   help="auto: given weights, else depth-and-edge (default); photo: the experimental "
                        "segmenter for photos without depth (docs/perception-photos.md)")
    p.add_argument("--out", required=True, help="scene JSON to write")
    p.add_argument("--overlay", help="PNG of masks, rectangles and box ids over the RGB")
    p.add_argument("--masks", help="uint16 PNG label image (label k = box with mask_label k)")
    p.add_argument("--front-distance", type=float, metavar="M",
                   help="no depth: box fronts are a plane this far from the camera (m)")
    p.add_argument("--box-size", type=float, nargs=2, metavar=("W", "H"),
                   help="no depth: derive the distance from a known front-face size (m)")
    p.add_argument("--shelf", type=float, nargs=3, metavar=("WIDTH", "DEPTH", "HEIGHT"),
                   help="shelf interior in metres (default 1.0 0.30 1.60)")
    p.add_argument("--report", help="JSON with warnings, adjustments, faces and timing")


def run(args: argparse.Namespace) -> int:
    import cv2

    from perception.capture import load_capture
    from perception.errors import PerceptionError
    from perception.pipeline import perceive
    from perception.scene import Shelf, write_json
    from perception.segment import load_segmenter

    if args.front_distance is not None and args.front_distance <= 0:
        raise PerceptionError(f"--front-distance must be > 0 m, got {args.front_distance}")
    kind = "yolo" if args.weights and args.segmenter == "auto" else args.segmenter
    capture = load_capture(args.rgb, args.depth, args.camera)
    seg = load_segmenter(args.weights, kind)
    shelf = Shelf(*args.shelf) if args.shelf else Shelf()
    result = perceive(capture, seg, shelf, front_distance=args.front_distance,
                      box_size=tuple(args.box_size) if args.box_size else None, origin=args.camera)
    result.scene.save(args.out)
    if args.overlay:
        if not cv2.imwrite(args.overlay, cv2.cvtColor(result.overlay, cv2.COLOR_RGB2BGR)):
            raise PerceptionError(f"{args.overlay}: cannot write the overlay image")
    if args.masks:
        if not cv2.imwrite(args.masks, result.masks):
            raise PerceptionError(f"{args.masks}: cannot write the mask image")
    if args.report:
        write_json(args.report, result.summary())
    for w in result.warnings:
        print(f"warning: {w}", file=sys.stderr)
    for a in result.adjustments:
        print(f"adjusted: {a}", file=sys.stderr)
    print(f"{len(result.scene.boxes)} boxes -> {args.out} ({result.segmenter}, "
          f"{result.timing['total']:.2f} s)")
    return 0
