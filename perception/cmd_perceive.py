"""`shelfpick perceive`: one RGB(-D) capture to a scene, an overlay and instance masks."""
from __future__ import annotations

import argparse
import logging
import math
from pathlib import Path

from shelfpick.perception.errors import PerceptionError

log = logging.getLogger(__name__)

HELP = "perceive a scene (depth_known false) from an RGB image, a depth image and a camera file"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rgb", required=True, help="colour image (PNG/JPEG)")
    p.add_argument("--depth", help="depth image (uint16 PNG in camera depth_scale units, or .npy)")
    p.add_argument("--camera", required=True, help="shelfpick.camera/1 file (intrinsics + pose)")
    p.add_argument("--weights", help="YOLO11n-seg weights (.pt); implies --segmenter yolo "
                   "(with --segmenter learned: a shelfpick-learned checkpoint)")
    p.add_argument("--segmenter", choices=("auto", "depth", "photo", "yolo", "learned"), default="auto",
                   help="auto (default): given weights, else the learned segmenter (the depth-and-edge "
                        "rules where its weights or torch are missing); depth: the rules; photo: the "
                        "experimental segmenter for photos without depth (docs/perception-photos.md)")
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
    p.add_argument("--no-catalogue", action="store_true",
                   help="the boxes are not of the reference types (carton 23x31x25, cube 20, long 50x17x17 cm): "
                        "never join or cut faces toward them (other stock, e.g. a pallet of 34x25 cm cartons)")


def _check_numbers(args: argparse.Namespace) -> None:
    """Options that are sizes or distances: finite, > 0 and within the scene format's bounds (a
    scene written with a 0 m or a 1e300 m wide shelf cannot be loaded again)."""
    from shelfpick.perception.scene import BOX_SIZE_M, CAMERA_POSITION_M, SHELF_M

    for flag, vals, (lo, hi) in (
            ("--front-distance", [args.front_distance] if args.front_distance is not None else [],
             (0.05, CAMERA_POSITION_M)),
            ("--box-size", list(args.box_size or []), BOX_SIZE_M), ("--shelf", list(args.shelf or []), SHELF_M)):
        bad = [v for v in vals if not (math.isfinite(v) and v > 0)]
        if bad:
            raise PerceptionError(f"{flag}: sizes and distances must be finite and > 0 m, got "
                                  f"{' '.join(f'{v:g}' for v in vals)}")
        if any(not lo <= v <= hi for v in vals):
            raise PerceptionError(f"{flag}: must be within [{lo:g}, {hi:g}] m, got {' '.join(f'{v:g}' for v in vals)}")


def _check_depth_given(args: argparse.Namespace) -> None:
    """An RGB-D capture folder (as `render`, a RealSense capture or Capture.save write it) perceived
    without its depth image: the distance to every box would be a guess (issue 13: a shelf-sized
    box, exit 0). Refused unless the colour alone is asked for with a distance or a box size."""
    if args.depth is not None or args.front_distance is not None or args.box_size is not None:
        return
    rgb = Path(args.rgb)
    beside = [rgb.with_name(n) for n in ("depth.png", "depth.npy") if rgb.with_name(n).is_file()]
    if beside:
        raise PerceptionError(f"--depth: not given, but {beside[0]} lies beside {rgb}: give --depth {beside[0]} "
                              "(without it the distance to every box is a guess), or --front-distance M / "
                              "--box-size W H to perceive the colour image alone")


def _implausible(result, shelf) -> str | None:
    """Why a colour-only result is no shelf of boxes (None when it may be one).

    Without a depth image the distance to every face is one guess (a plane square to the optical
    axis, or --front-distance / --box-size): on a pitched camera or a busy background a face can
    come out as the whole shelf, or, far off axis, kilometres wide. Such a scene is refused rather
    than written: a planner would treat it as real."""
    for b in result.scene.boxes:
        w, h = b.size[0], b.size[2]
        if w > 0.9 * shelf.width or h > 0.9 * shelf.height:
            return f"box {b.id} came out {w:.2f} x {h:.2f} m, the size of the shelf"
    for box_id, f in (result.summary().get("faces") or {}).items():
        x = f.get("center", [0.0])[0]
        if f.get("width", 0.0) > 2 * shelf.width or abs(x) > shelf.width:
            return f"the face of {box_id} came out {f.get('width', 0.0):.2f} m wide at x = {x:.2f} m"
    return None


def _write(path: str, what: str, write) -> None:
    """Run `write()`; a folder that cannot be made or a file that cannot be written is the
    user's to fix, so it becomes a one-line PerceptionError naming the file."""
    import cv2

    try:
        ok = write()
    except (OSError, cv2.error) as exc:
        why = getattr(exc, "strerror", None) or str(exc).strip().splitlines()[-1]
        raise PerceptionError(f"{path}: cannot write the {what} ({why})") from None
    if ok is False:
        raise PerceptionError(f"{path}: cannot write the {what} (an existing folder and a .png name expected)")


def run(args: argparse.Namespace) -> int:
    import cv2

    from shelfpick.perception.capture import check_depth_structure, load_capture
    from shelfpick.perception.heap_pages import keep_freed_pages
    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.scene import Shelf, output_path, write_json
    from shelfpick.perception.segment import load_segmenter

    _check_numbers(args)
    keep_freed_pages()        # this process perceives: freed arrays' pages kept (heap_pages)
    for flag in ("out", "overlay", "masks", "report"):       # before any work: never onto a device or FIFO
        if getattr(args, flag):
            output_path(getattr(args, flag), f"--{flag}")
    if args.weights and not str(args.weights).lower().endswith(".pt"):
        raise PerceptionError(f"{args.weights}: --weights must be a YOLO11n-seg .pt checkpoint "
                              "(as `shelfpick train-seg` writes)")
    if args.masks and not str(args.masks).lower().endswith(".png"):
        raise PerceptionError(f"{args.masks}: --masks must be a .png file (uint16 labels; JPEG cannot hold them)")
    kind = "yolo" if args.weights and args.segmenter == "auto" else args.segmenter
    capture = load_capture(args.rgb, args.depth, args.camera)   # bad files first, each in one line
    if capture.depth is not None:
        check_depth_structure(capture.depth, str(args.depth))
    seg = load_segmenter(args.weights, kind)
    _check_depth_given(args)
    shelf = Shelf(*args.shelf) if args.shelf else Shelf()
    extra = {"catalogue": None} if getattr(args, "no_catalogue", False) else {}
    result = perceive(capture, seg, shelf, front_distance=args.front_distance,
                      box_size=tuple(args.box_size) if args.box_size else None, origin=args.camera, **extra)
    if capture.depth is None:
        why = _implausible(result, shelf)
        if why:
            raise PerceptionError(f"--depth: not given, and from the colour image alone {why}; give the "
                                  "capture's depth image (--depth), or the distance to the box fronts "
                                  "(--front-distance M or --box-size W H), or use --segmenter photo, made for photos; nothing written")
    _write(args.out, "scene", lambda: result.scene.save(args.out))
    if args.overlay:
        _write(args.overlay, "overlay image",
               lambda: cv2.imwrite(args.overlay, cv2.cvtColor(result.overlay, cv2.COLOR_RGB2BGR)))
    if args.masks:
        _write(args.masks, "mask image", lambda: cv2.imwrite(args.masks, result.masks))
    if args.report:
        _write(args.report, "report", lambda: write_json(args.report, result.summary()))
    for w in result.warnings:
        log.warning("%s", w)
    for a in result.adjustments:
        log.info("adjusted: %s", a)
    regions = result.scene.unexplained
    told = "" if regions is None else f", {len(regions)} unexplained region{'s' if len(regions) != 1 else ''}"
    log.info("%d boxes%s -> %s (%s, %.2f s)", len(result.scene.boxes), told, args.out, result.segmenter,
             result.timing["total"])
    return 0
