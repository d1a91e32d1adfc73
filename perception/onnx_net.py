"""The learned segmenter's network on ONNX Runtime: numpy in, numpy out, no torch.

Why: the console's default segmenter needs only the network's forward pass; ONNX Runtime runs
the exported graph (`perception/training/onnx_export.py`) in a ~80 MB install where torch and its CUDA
libraries take ~6 GB. The file carries the checkpoint's inference settings as metadata
(`shelfpick.config`, JSON), read here without torch.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from shelfpick.perception.errors import PerceptionError

META_PREFIX = "shelfpick."


def _ort():
    try:
        import onnxruntime
    except ImportError:
        raise PerceptionError("the learned segmenter needs onnxruntime, which is not installed here: "
                              "pip install 'shelfpick[perception]'") from None
    return onnxruntime


class OnnxNet:
    """`net(x) -> logits`: x is 1x3xHxW float32 (H, W multiples of 32), logits 1x3x(H/4)x(W/4).
    `threads`: ONNX Runtime's intra-op threads (None: its own choice, one per core)."""

    def __init__(self, path: str | Path, threads: int | None = 1):
        ort = _ort()
        path = Path(path)
        if not path.is_file():
            raise PerceptionError(f"{path}: learned segmenter weights not found")
        opts = ort.SessionOptions()
        opts.intra_op_num_threads = 0 if threads is None else int(threads)
        opts.inter_op_num_threads = 1
        opts.log_severity_level = 3          # errors only: a shape warning is not the operator's
        try:
            self.session = ort.InferenceSession(str(path), opts, providers=["CPUExecutionProvider"])
            meta = self.session.get_modelmeta().custom_metadata_map
        except Exception as exc:  # noqa: BLE001 - any unreadable file is the user's to replace
            why = str(exc).strip().splitlines()[0][:120] if str(exc).strip() else type(exc).__name__
            raise PerceptionError(f"{path}: not an ONNX model ({why})") from None
        if META_PREFIX + "config" not in meta:
            raise PerceptionError(f"{path}: not a shelfpick-learned ONNX file (no {META_PREFIX}config metadata;"
                                  " export it with python -m shelfpick.perception.training.onnx_export)")
        self.path, self.threads = path, threads
        self.metadata = {k[len(META_PREFIX):]: json.loads(v) for k, v in meta.items() if k.startswith(META_PREFIX)}
        self.input_name = self.session.get_inputs()[0].name

    def __call__(self, x: np.ndarray) -> np.ndarray:
        if x.ndim != 4 or x.shape[2] % 32 or x.shape[3] % 32:
            raise ValueError(f"the network takes 1x3xHxW with H and W multiples of 32, not {x.shape}")
        return self.session.run(None, {self.input_name: np.ascontiguousarray(x, np.float32)})[0]

    def with_threads(self, threads: int | None) -> OnnxNet:
        """The same file in a session with `threads` threads (a session's threads are fixed)."""
        return self if threads == self.threads else OnnxNet(self.path, threads)
