"""Export a shelfpick-learned checkpoint (.pt, torch) to the ONNX file the console runs.

Why: the learned segmenter's network is the only part of the default console that needed torch
(a 6 GB install with its CUDA libraries); ONNX Runtime runs the same network from one file in a
~80 MB install. Training stays on torch (`train_learned.py`, the `train` extra); after a new
checkpoint, export it once:

    python -m shelfpick.perception.training.onnx_export                       # static/weights/shelfpick-learned.pt -> .onnx
    python -m shelfpick.perception.training.onnx_export --weights /tmp/w.pt --out /tmp/w.onnx

Needs torch and onnx (the `train` extra). It uses torch's TorchScript exporter (`dynamo=False`):
the dynamo exporter (torch 2.14's default, which needs onnxscript) had not finished after 17 min
on this project's 2 shared cores; this one takes seconds. The graph takes a 1x3xHxW float32 image
of any H and W that are multiples of 32 (what `LearnedSegmenter` feeds it) and gives the 3 class
logits at 1/4 of it; the checkpoint's `config`, `decoder_channels` and `meta` travel as the file's
metadata (`shelfpick.config` etc., JSON), so inference needs no torch to read them.
"""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.onnx_net import META_PREFIX
from shelfpick.perception.segment_learned import LEARNED_ONNX, LEARNED_WEIGHTS, load_checkpoint

OPSET = 17


def traceable(model):
    """The network in a form the TorchScript tracer keeps for every input size that is a multiple
    of 32: each 'SAME' pad as its constant and each decoder upsampling as x2.

    Why: the tracer turns Python arithmetic on shapes into the example's numbers (the pads of a
    96 px example crop a 352 px input; `interpolate(size=tap.shape)` stays at the example's size).
    At a multiple of 32 every stride-2 conv meets an even size, where TF's 'SAME' pad is
    max(k - s, 0) whatever the size, and each tap is exactly twice the map below it, where bilinear
    x2 samples the same points as `size=` (scale 0.5 either way). Changes the model in place."""
    import torch

    F = torch.nn.functional

    def constant_pad(conv):
        k, s = conv.kernel_size[0], conv.stride[0]
        p = max(k - s, 0)

        def forward(x):
            x = F.pad(x, [p // 2, p - p // 2, p // 2, p - p // 2])
            return F.conv2d(x, conv.weight, conv.bias, conv.stride, 0, conv.dilation, conv.groups)
        return forward

    for m in model.modules():
        if type(m).__name__ == "SamePadConv":
            m.forward = constant_pad(m)

    class Traceable(torch.nn.Module):
        def __init__(self, net):
            super().__init__()
            self.net = net

        def forward(self, x):
            net = self.net
            taps = net.features(x)
            y = net.lateral[-1](taps[-1])
            for i in range(len(taps) - 2, -1, -1):
                y = F.interpolate(y, scale_factor=2.0, mode="bilinear", align_corners=False)
                y = net.smooth[i](y + net.lateral[i](taps[i]))
            return net.head(y)

    return Traceable(model).eval()


def export(weights: str | Path = LEARNED_WEIGHTS, out: str | Path = LEARNED_ONNX) -> Path:
    """Write `out` from the checkpoint `weights` (float32; ONNX Runtime folds the batch norms
    when it loads the file); the height and width stay free. Returns `out`."""
    import onnx
    import torch

    model, config, meta = load_checkpoint(weights)
    ck = torch.load(str(weights), map_location="cpu", weights_only=True)
    out = Path(out)
    tmp = out.with_name(out.name + ".tmp")
    x = torch.zeros(1, 3, 96, 128)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")   # the tracer's notes on the constant pads (see `traceable`)
        torch.onnx.export(traceable(model), (x,), str(tmp), dynamo=False, opset_version=OPSET,
                          input_names=["image"], output_names=["logits"],
                          dynamic_axes={"image": {2: "height", 3: "width"}, "logits": {2: "height/4", 3: "width/4"}})
    proto = onnx.load(str(tmp))
    props = {"config": config.to_json(), "decoder_channels": int(ck.get("decoder_channels", 64)), "meta": meta,
             "source": Path(weights).name}
    for key, value in props.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = META_PREFIX + key, json.dumps(value, sort_keys=True)
    onnx.checker.check_model(proto)
    onnx.save_model(proto, str(tmp))
    tmp.replace(out)
    return out


def main(argv: list[str] | None = None) -> int:
    """The command line (see the module docstring); a bad checkpoint is one line, exit 2."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--weights", default=str(LEARNED_WEIGHTS), help="shelfpick-learned checkpoint (.pt)")
    p.add_argument("--out", default=str(LEARNED_ONNX), help="the ONNX file to write")
    a = p.parse_args(argv)
    try:
        out = export(a.weights, a.out)
    except PerceptionError as exc:
        print(f"onnx_export: {exc}", file=sys.stderr)
        return 2
    print(f"{out}: {out.stat().st_size / 2**20:.1f} MiB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
