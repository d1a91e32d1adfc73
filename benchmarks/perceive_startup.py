"""Where one `shelfpick perceive` process spends its time: the child of `perceive_speed.py --mode split`.

Run as a fresh process per frame (`python benchmarks/perceive_startup.py FOLDER OUT`), it does
what `shelfpick perceive --out --report --masks --overlay` does (console/cli.py, then
perception/cmd_perceive.py), in the same order, and stamps each phase with `time.time()` (so the
parent can count the interpreter's start before the first stamp and its exit after the last):

- `cli_import`: `shelfpick.console.cli` and its parser, which imports every subcommand's module
  (what any subcommand pays);
- `perceive_imports`: what `cmd_perceive.run` imports (cv2, capture, pipeline, scene, segment);
- `read`: `load_capture` and the depth check;
- `seg_import`: the learned segmenter's module (with the depth-and-edge rules it imports);
- `session`: the ONNX Runtime session (`AutoSegmenter.choose`, which the CLI pays inside `perceive`);
- `perceive`: `pipeline.perceive`, of it `forward_first` (the network's first pass in this process);
- `forward_again`: the same input through the network twice more, the faster (what a warm pass
  costs; not part of the CLI's work: timed after the outputs are written, left out of every phase);
- `write`: the scene, overlay, masks and report;
- then what `cli.main` does last in a `perceive` process (`_ending_process`, where the tree has it),
  and the interpreter's exit, timed by the parent.

Only `time`, `sys`, `json` are imported before the first stamp. Prints one JSON line.
"""
from __future__ import annotations

import time

T0 = time.time()

import json  # noqa: E402
import sys  # noqa: E402


def main(folder: str, out: str) -> dict:
    stamps = {"start": T0}

    def stamp(name: str) -> None:
        stamps[name] = time.time()

    from shelfpick.console.cli import build_parser

    build_parser()                 # imports every subcommand's module, as `shelfpick` does
    stamp("cli_import")
    import cv2

    from shelfpick.perception.capture import check_depth_structure, load_capture
    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.scene import write_json
    from shelfpick.perception.segment import load_segmenter
    stamp("perceive_imports")
    cap = load_capture(f"{folder}/rgb.png", f"{folder}/depth.png", f"{folder}/camera.json")
    check_depth_structure(cap.depth, f"{folder}/depth.png")
    stamp("read")
    import shelfpick.perception.segment_learned  # noqa: F401
    from shelfpick.perception.onnx_net import OnnxNet
    stamp("seg_import")
    seg = load_segmenter(None, "auto")
    seg.choose(True)
    stamp("session")
    calls: list[tuple[float, object]] = []
    inner = OnnxNet.__call__

    def tapped(self, x):
        t = time.time()
        y = inner(self, x)
        calls.append((time.time() - t, (self, x)))
        return y

    OnnxNet.__call__ = tapped
    res = perceive(cap, seg, origin=f"{folder}/camera.json")
    stamp("perceive")
    res.scene.save(f"{out}/perceived.json")
    cv2.imwrite(f"{out}/overlay.png", cv2.cvtColor(res.overlay, cv2.COLOR_RGB2BGR))
    cv2.imwrite(f"{out}/perceived_masks.png", res.masks)
    write_json(f"{out}/report.json", res.summary())
    stamp("write")
    OnnxNet.__call__ = inner
    again = []
    for _ in range(2):
        t = time.time()
        inner(*calls[0][1])
        again.append(time.time() - t)
    names = list(stamps)
    done = time.time()
    row = {n: stamps[n] - stamps[p] for p, n in zip(names, names[1:])}
    row.update(start=T0, end=done, forward_first=calls[0][0] if calls else 0.0,
               forward_again=min(again), forward_calls=len(calls), total=stamps["write"] - T0)
    return row


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], sys.argv[2])), flush=True)
    from shelfpick.console import cli

    ending = getattr(cli, "_ending_process", None)      # what cli.main does last in a perceive process
    if ending is not None:
        ending()
