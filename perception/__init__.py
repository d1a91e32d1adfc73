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
    "perceive": "shelfpick.perception.pipeline", "Perception": "shelfpick.perception.pipeline",
    "DEFAULT_CATALOGUE": "shelfpick.perception.pipeline",
    "Capture": "shelfpick.perception.capture", "load_capture": "shelfpick.perception.capture",
    "Scene": "shelfpick.perception.scene", "Shelf": "shelfpick.perception.scene", "Box": "shelfpick.perception.scene",
    "Camera": "shelfpick.perception.scene", "BOX_TYPES": "shelfpick.perception.scene",
    "Segmenter": "shelfpick.perception.segment", "load_segmenter": "shelfpick.perception.segment",
    "Catalogue": "shelfpick.perception.box_catalogue", "apply_catalogue": "shelfpick.perception.box_catalogue",
    "FrontFace": "shelfpick.perception.faces", "make_valid": "shelfpick.perception.boxes",
    "default_camera": "shelfpick.perception.render",   # (render() itself: perception.render is also the module's name)
    "ShelfpickError": "shelfpick.perception.errors", "FormatError": "shelfpick.perception.errors",
    "SceneError": "shelfpick.perception.errors", "PerceptionError": "shelfpick.perception.errors",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'perception' has no attribute {name!r}")
