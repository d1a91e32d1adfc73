"""`shelfpick calibrate`: the camera's pose in the shelf frame from an image of a ChArUco board."""
from __future__ import annotations

import argparse
import logging
import math

from shelfpick.perception.errors import PerceptionError

log = logging.getLogger(__name__)

HELP = "camera pose in the shelf frame from one image of a printed ChArUco board at the shelf"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--rgb", help="image of the board, taken by the camera to calibrate")
    p.add_argument("--camera", help="shelfpick.camera/1 file with the camera's intrinsics (its pose is replaced)")
    p.add_argument("--out", help="camera file to write (intrinsics + the recovered pose)")
    p.add_argument("--board", type=int, nargs=2, default=(8, 6), metavar=("SQUARES_X", "SQUARES_Y"),
                   help="squares across and down the print (default 8 6)")
    p.add_argument("--square", type=float, default=0.06, help="printed square side in m (default 0.06)")
    p.add_argument("--marker", type=float, default=0.045, help="printed marker side in m (default 0.045)")
    p.add_argument("--dictionary", default="DICT_5X5_100", help="ArUco dictionary (default DICT_5X5_100)")
    p.add_argument("--plane", choices=("front", "floor"), default="front",
                   help="front: standing in the shelf's front plane facing the camera (a pallet seen from "
                        "above: lying on its top layer); floor: lying on the shelf floor (docs/cameras.md)")
    p.add_argument("--origin", type=float, nargs=3, default=(0.0, 0.0, 0.0), metavar=("X", "Y", "Z"),
                   help="the board's top-left chessboard corner in the shelf frame, m (default 0 0 0)")
    p.add_argument("--write-board", metavar="PNG", help="write the board to print (100 px per square) and stop")


def run(args: argparse.Namespace) -> int:
    import cv2

    from shelfpick.perception.calibrate import BoardPlacement, BoardSpec, board_image, calibrate
    from shelfpick.perception.capture import read_rgb
    from shelfpick.perception.scene import Camera, output_path

    for name in ("square", "marker"):
        v = getattr(args, name)
        if not (math.isfinite(v) and v > 0):
            raise PerceptionError(f"--{name} must be a positive size in metres, got {v!r}")
    if not all(math.isfinite(v) for v in args.origin):
        raise PerceptionError(f"--origin must be three finite numbers (m), got {list(args.origin)}")
    spec = BoardSpec(args.board[0], args.board[1], args.square, args.marker, args.dictionary)
    for flag in ("write_board", "out"):          # never onto a device, FIFO or folder
        if getattr(args, flag):
            output_path(getattr(args, flag), "--" + flag.replace("_", "-"))
    if args.write_board:
        img = board_image(spec)
        if not args.write_board.lower().endswith(".png") or not cv2.imwrite(args.write_board, img):
            raise PerceptionError(f"{args.write_board}: cannot write the board (a writable .png path?)")
        log.info("board %dx%d, squares %.3f m: print at %.1f px/mm so a square measures %g mm",
                 spec.squares_x, spec.squares_y, spec.square, 100 / (spec.square * 1000), spec.square * 1000)
        return 0
    missing = [o for o in ("rgb", "camera", "out") if not getattr(args, o)]
    if missing:
        raise PerceptionError(f"calibrate needs {', '.join('--' + m for m in missing)} (or --write-board PNG)")
    camera = Camera.load(args.camera)
    rgb = read_rgb(args.rgb)
    if (rgb.shape[1], rgb.shape[0]) != (camera.width, camera.height):
        raise PerceptionError(f"{args.camera}: camera is {camera.width}x{camera.height} but {args.rgb} is "
                              f"{rgb.shape[1]}x{rgb.shape[0]}")
    cal = calibrate(rgb, camera, spec, BoardPlacement(args.plane, tuple(args.origin)), origin=args.rgb)
    try:
        cal.camera.save(args.out)
    except OSError as exc:
        raise PerceptionError(f"{args.out}: cannot write the camera file ({exc.strerror or exc})") from None
    log.info("%d board corners, reprojection error %.2f px: camera at %s m in the shelf frame -> %s",
             cal.corners, cal.rms_px, [round(v, 4) for v in cal.camera.position], args.out)
    if cal.rms_px > 1.0:
        log.warning("reprojection error %.2f px is high: a bent or mis-sized print, or the wrong intrinsics?",
                    cal.rms_px)
    return 0
