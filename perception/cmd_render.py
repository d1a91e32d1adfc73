"""`shelfpick render SCENE --out DIR`: a synthetic RGB-D capture with ground-truth masks."""
from __future__ import annotations

import argparse
import logging
import os
import time
from contextlib import contextmanager
from typing import Iterator

from shelfpick.perception.stdio import redirected_fds

log = logging.getLogger(__name__)

HELP = "render a scene file into rgb.png, depth.png, camera.json, masks.png and masks.json"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("scene", help="a shelfpick.scene/1 file")
    parser.add_argument("--out", required=True, help="output folder (created)")
    parser.add_argument("--camera", help="a shelfpick.camera/1 file (default: the scene's camera, "
                                         "else a D435 1.05 m in front of the shelf)")
    parser.add_argument("--seed", type=int, default=0, help="looks, lighting and noise (default 0)")
    parser.add_argument("--no-noise", action="store_true", help="exact depth, clean colour image")


@contextmanager
def c_stdout_to_stderr(keep_stderr: bool = False) -> Iterator[None]:
    """pybullet's C code printf()s `argv[0]=` on stdout when it connects (and its build time on
    stderr when imported): that would land among what a command was asked to print. With -v
    (debug) or `keep_stderr` (a progress bar runs meanwhile) both go to stderr; otherwise nowhere
    (Python's own errors are raised, and printed after the file descriptors are back)."""
    verbose = keep_stderr or log.isEnabledFor(logging.DEBUG)
    with redirected_fds(2 if verbose else os.devnull, None if verbose else os.devnull):
        yield


def run(args: argparse.Namespace) -> int:
    from shelfpick.perception.render import render
    from shelfpick.perception.scene import Camera, Scene

    scene = Scene.load(args.scene)
    camera = Camera.load(args.camera) if args.camera else None
    t0 = time.perf_counter()
    with c_stdout_to_stderr():
        capture = render(scene, camera, seed=args.seed, noise=not args.no_noise)
    dt = time.perf_counter() - t0
    paths = capture.save(args.out)
    log.info("rendered %d boxes (%d visible) in %.2f s -> %s", len(scene.boxes), len(capture.labels), dt,
             ", ".join(str(p) for p in paths.values()))
    return 0
