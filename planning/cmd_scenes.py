"""`shelfpick scenes`: write seeded synthetic shelves (structured, unstructured, or a stack kind
where highest-first collapses often) as scene files, settled with their true masses."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from shelfpick.perception.errors import FormatError

log = logging.getLogger(__name__)

HELP = "generate synthetic shelves (settled in physics) as shelfpick.scene/1 files"


def parse_range(text: str) -> tuple[int, int]:
    """'8-14' -> (8, 14); '10' -> (10, 10)."""
    try:
        if "-" in text:
            lo, hi = (int(v) for v in text.split("-", 1))
        else:
            lo = hi = int(text)
    except ValueError:
        raise FormatError("--boxes", "", f"expected MIN-MAX (e.g. 8-14), got {text!r}") from None
    from shelfpick.planning.shelves import MAX_BOXES

    if not 1 <= lo <= hi <= MAX_BOXES:
        raise FormatError("--boxes", "", f"expected 1 <= MIN <= MAX <= {MAX_BOXES}, got {text!r}")
    return lo, hi


def scene_seed(seed: int, index: int) -> int:
    """The generator seed of the index-th scene of a run (independent of --count)."""
    return int(seed) * 100003 + index


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--kind", choices=("structured", "unstructured", "proud", "bridge", "lean", "overhang"),
                        required=True,
                        help="structured / unstructured stacks, or one where highest-first collapses often: "
                             "proud (boxes 1-6 cm proud of the front carrying others), bridge (long boxes "
                             "across two supports), lean (a long box leaning on a stack), overhang (turned, "
                             "shifted columns)")
    parser.add_argument("--count", type=int, default=20, help="number of scenes (default 20)")
    parser.add_argument("--seed", type=int, default=0, help="base seed (default 0)")
    parser.add_argument("--out", required=True, help="output folder")
    parser.add_argument("--boxes", default=None,
                        help="boxes per scene, MIN-MAX or N (default: 8-14 drawn per scene)")
    parser.add_argument("--masses", action=argparse.BooleanOptionalAction, default=None,
                        help="true per-box masses drawn in 0.3-5 kg (default: on for proud, bridge, lean, "
                             "overhang; off for structured and unstructured, which keep the method's density)")


def run(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from shelfpick.planning.shelves import generate

    if args.count < 1:
        raise FormatError("--count", "", f"expected a positive number, got {args.count!r}")
    rng_range = parse_range(args.boxes) if args.boxes else None
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise FormatError(str(out), "", f"cannot create the output folder ({exc.strerror})") from None
    quiet = not log.isEnabledFor(logging.INFO)
    for i in tqdm(range(args.count), desc=f"{args.kind} shelves", unit="scene", disable=quiet):
        s = scene_seed(args.seed, i)
        n = None
        if rng_range is not None:
            n = int(np.random.default_rng([s & 0xFFFFFFFF, 7]).integers(rng_range[0], rng_range[1] + 1))
        scene = generate(args.kind, s, n, masses=args.masses)
        scene.save(out / f"{args.kind}-{args.seed}-{i:04d}.json")
    log.info("wrote %d %s scenes to %s", args.count, args.kind, out)
    return 0
