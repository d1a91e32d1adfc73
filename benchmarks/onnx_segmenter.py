"""Could the learned (YOLO11n-seg) segmenter ship on ONNX Runtime instead of torch + ultralytics?

Measures, on one rendered demo shelf: the network's forward pass in torch (as ultralytics runs it)
and in ONNX Runtime (the same weights exported by ultralytics to ONNX), both on one thread, the
largest difference between their raw outputs, the weight file sizes, and the installed size of
the packages each needs. Only the forward pass: the mask post-processing (NMS, prototype masks)
that ultralytics does after it would have to be written for ONNX Runtime.

Needs torch, ultralytics, onnx (for the export) and onnxruntime importable, e.g.
    pip install --target /tmp/onnxpkgs --no-deps onnx onnxruntime ml_dtypes flatbuffers coloredlogs humanfriendly
    PYTHONPATH=/tmp/onnxpkgs OMP_NUM_THREADS=1 nice -n 10 .venv/bin/python benchmarks/onnx_segmenter.py
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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


def timed(fn, runs: int) -> tuple[float, float]:
    fn()   # warm-up
    times = []
    for _ in range(runs):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1000, min(times) * 1000


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default=str(ROOT / "static" / "weights" / "shelfpick-seg.pt"),
                   help="YOLO11n-seg weights (.pt)")
    p.add_argument("--imgsz", type=int, default=320, help="network input size (the segmenter's default: 320)")
    p.add_argument("--runs", type=int, default=30, help="timed forward passes each (default 30)")
    p.add_argument("--out", help="also write the markdown here")
    return p.parse_args(argv)


def demo_input(imgsz: int):
    """The rendered demo shelf as the network's input: 1 x 3 x imgsz x imgsz, float32 in [0, 1]."""
    import cv2
    import numpy as np

    from perception.render import render
    from perception.scene import Scene

    capture = render(Scene.load(ROOT / "static" / "demo" / "demo-small-6.json"), seed=0)
    img = cv2.resize(capture.rgb, (imgsz, imgsz)).astype(np.float32) / 255.0
    return np.ascontiguousarray(img.transpose(2, 0, 1)[None])


def measure(args: argparse.Namespace) -> dict:
    """Export the weights to ONNX, time both forward passes on one thread, compare their raw outputs."""
    import numpy as np
    import onnxruntime as ort
    import torch
    from ultralytics import YOLO

    torch.set_num_threads(1)
    x = demo_input(args.imgsz)
    with tempfile.TemporaryDirectory() as tmp:
        pt = Path(tmp) / "seg.pt"
        shutil.copy(args.weights, pt)
        model = YOLO(str(pt))
        onnx_path = Path(model.export(format="onnx", imgsz=args.imgsz, simplify=False, dynamic=False, verbose=False))
        onnx_mib = onnx_path.stat().st_size / 2**20
        net = model.model.eval()
        xt = torch.from_numpy(x)
        with torch.no_grad():
            ref = net(xt)
            while isinstance(ref, (list, tuple)):   # (detections + mask coefficients, extras)
                ref = ref[0]
            ref0 = ref.numpy()
            torch_ms = timed(lambda: net(xt), args.runs)
        so = ort.SessionOptions()
        so.intra_op_num_threads = 1
        so.inter_op_num_threads = 1
        sess = ort.InferenceSession(str(onnx_path), so, providers=["CPUExecutionProvider"])
        name = sess.get_inputs()[0].name
        out0 = sess.run(None, {name: x})[0]
        ort_ms = timed(lambda: sess.run(None, {name: x}), args.runs)
    return {"torch_ms": torch_ms, "ort_ms": ort_ms, "onnx_mib": onnx_mib,
            "diff": float(np.abs(out0 - ref0).max()), "scale": float(np.abs(ref0).max()),
            "torch_version": torch.__version__, "ort_version": ort.__version__}


def report(args: argparse.Namespace, m: dict) -> str:
    """The markdown written up in docs/results/onnx-segmenter.md, with the packages' installed sizes."""
    torch_ms, ort_ms = m["torch_ms"], m["ort_ms"]
    torch_pkgs = installed_mib("torch", "torchvision", "ultralytics")
    ort_pkgs = installed_mib("onnxruntime")
    return "\n".join([
        "# The YOLO11n-seg segmenter on ONNX Runtime vs torch", "",
        f"`PYTHONPATH=<onnx packages> OMP_NUM_THREADS=1 python benchmarks/onnx_segmenter.py "
        f"--imgsz {args.imgsz} --runs {args.runs}` (Python {sys.version.split()[0]}, torch {m['torch_version']}, "
        f"onnxruntime {m['ort_version']}, one thread each, {time.strftime('%Y-%m-%d')})", "",
        "| | torch + ultralytics | ONNX Runtime |", "|---|---:|---:|",
        f"| forward pass, median (min) ms | {torch_ms[0]:.1f} ({torch_ms[1]:.1f}) | {ort_ms[0]:.1f} ({ort_ms[1]:.1f}) |",
        f"| weights file MiB | {Path(args.weights).stat().st_size / 2**20:.1f} (.pt) | {m['onnx_mib']:.1f} (.onnx) |",
        f"| installed packages MiB | {torch_pkgs:.0f} (torch, torchvision, ultralytics) | {ort_pkgs:.0f} (onnxruntime) |",
        "", "Installed sizes are the packages' own folders; torch from PyPI also pulls the CUDA libraries",
        "(nvidia-*, triton), which the `learned` extra's venv counts (docs/results/install-footprint.md).",
        "", f"Largest difference between the raw outputs: {m['diff']:.2e} (outputs up to {m['scale']:.1f}).",
        "Forward pass only: the mask post-processing ultralytics does after it (confidence filter, NMS,",
        "prototype masks scaled to the image) is not measured and would have to be written for ONNX Runtime.",
    ]) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Measure, print the markdown, and write it to --out when given."""
    args = parse_args(argv)
    os.environ.setdefault("YOLO_OFFLINE", "1")
    os.environ.setdefault("YOLO_CONFIG_DIR", str(ROOT / ".yolo"))
    md = report(args, measure(args))
    print(md)
    if args.out:
        Path(args.out).write_text(md, encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
