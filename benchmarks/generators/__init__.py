"""Frame generators that share no code or assets with the training renderer (issue 31).

`write_frame(scene, look, seed, out_dir)` writes what `shelfpick perceive` reads (rgb.png,
depth.png in millimetres, camera.json) plus the ground truth (masks.png, masks.json: label -> box
id, as `Capture.save` writes them) and meta.json. The looks are in `looks.py`, the ray caster in
`raycast.py`; their roles (train / tune / held out) are fixed in docs/perception.md, "Roles".

    .venv/bin/python -m benchmarks.generators --look stereo --scene ../shared/judge/scenes/s00.json \
        --seed 0 --out /tmp/frames/s00
"""
from __future__ import annotations

import json
import zlib
from pathlib import Path

import numpy as np

LOOK_NAMES = ("flat", "printed", "stereo", "labels")   # append only: the index seeds frame_rng


def frame_rng(look: str, scene_name: str, seed: int) -> np.random.Generator:
    """The frame's random draws: fixed by the look, the scene's name and the seed."""
    return np.random.default_rng([LOOK_NAMES.index(look), zlib.crc32(scene_name.encode()), seed])


def make_frame(scene: dict, look: str, seed: int, scene_name: str = ""):
    """The `looks.Frame` of a shelfpick.scene/1 dict."""
    from benchmarks.generators.looks import LOOKS

    if look not in LOOKS:
        raise ValueError(f"look: expected one of {', '.join(LOOKS)}, got {look!r}")
    return LOOKS[look](scene, frame_rng(look, scene_name, seed))


def write_frame(scene: dict, look: str, seed: int, out_dir: str | Path, scene_name: str = "") -> dict[str, Path]:
    """Render and write one capture folder; the paths written."""
    import cv2

    f = make_frame(scene, look, seed, scene_name)
    d = Path(out_dir)
    d.mkdir(parents=True, exist_ok=True)
    paths = {k: d / n for k, n in (("rgb", "rgb.png"), ("depth", "depth.png"), ("camera", "camera.json"),
                                    ("masks", "masks.png"), ("masks_json", "masks.json"), ("meta", "meta.json"))}
    cv2.imwrite(str(paths["rgb"]), cv2.cvtColor(f.rgb, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(paths["depth"]), np.clip(np.round(f.depth * 1000), 0, 65535).astype(np.uint16))
    cv2.imwrite(str(paths["masks"]), f.masks)
    paths["camera"].write_text(json.dumps(f.cam.json(0.001), indent=1), encoding="utf-8")
    paths["masks_json"].write_text(json.dumps({str(k): v for k, v in sorted(f.labels.items())}), encoding="utf-8")
    paths["meta"].write_text(json.dumps({"look": look, "seed": seed, "scene": scene_name}), encoding="utf-8")
    return paths
