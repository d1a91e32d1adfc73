"""shelfpick's perception: one RGB-D capture (or photo) in, a scene of boxes out.

The public API is listed in `__all__`; the names are imported when first used (PEP 562), so
that `import perception.cmd_perceive` for a CLI's ``--help`` does not load OpenCV or the
segmenters. Inside the package, imports sit at module level, except optional packages (OpenCV,
Pillow, tqdm, pybullet) in the modules that the core and a CLI's ``--help`` load, and torch,
ultralytics and pyrealsense2 anywhere. See docs/perception.md for the stages and
docs/ARCHITECTURE.md for the module map.
"""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "perceive": "perception.pipeline", "Perception": "perception.pipeline",
    "DEFAULT_CATALOGUE": "perception.pipeline",
    "Capture": "perception.capture", "load_capture": "perception.capture",
    "Scene": "perception.scene", "Shelf": "perception.scene", "Box": "perception.scene",
    "Camera": "perception.scene", "BOX_TYPES": "perception.scene",
    "Segmenter": "perception.segment", "load_segmenter": "perception.segment",
    "Catalogue": "perception.box_catalogue", "apply_catalogue": "perception.box_catalogue",
    "FrontFace": "perception.faces", "make_valid": "perception.boxes",
    "default_camera": "perception.render",   # (render() itself: perception.render is also the module's name)
    "ShelfpickError": "perception.errors", "FormatError": "perception.errors",
    "SceneError": "perception.errors", "PerceptionError": "perception.errors",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'perception' has no attribute {name!r}")
