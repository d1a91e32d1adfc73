"""The mask repairs the box catalogue explains, one module per kind of damage.

Each repair is a step `(masks, RepairContext) -> (masks, notes)`; `perception.box_catalogue`
runs them in order (`apply_catalogue`). Modules:

- `measure`: `RepairContext` (the capture, the catalogue, a `FaceCache`), `Measured`
- `crop`: a mask's bounding box and `Near` (the pixels within the join gap), so pixel tests run on crops
- `planes`: pixels on a face's plane; two pieces joined with the on-plane pixels between them
- `seams`: where a seam (colour line or step, depth step) runs across a face
- `joins`: `join_pieces` (a label, tape end or flap cut off a face; a face cut by a tape cross)
- `splits`: `split_faces` (flush faces of one colour merged; rows and staircases of them)
- `l_cuts`: `cut_l_shapes` (one box's strip merged with another's end)
- `stepped`: `split_stepped_faces`, `take_stepped_parts` (masks across a depth step)
- `bands`: `take_bridging_parts` (a tape band merged with the face above); `parts`: what it shares with `stepped`
- `regroup`: `regroup_pieces` (halves merged crosswise, re-cut at the faces' seams)
- `enclosed`: `absorb_enclosed` (a label or band inside a face)
- `border_cut`: `cut_directions`, `complete_cut_face` (faces cut by the image border)
"""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "RepairContext": "shelfpick.perception.repairs.measure", "FaceCache": "shelfpick.perception.repairs.measure",
    "Measured": "shelfpick.perception.repairs.measure",
    "join_pieces": "shelfpick.perception.repairs.joins", "split_faces": "shelfpick.perception.repairs.splits",
    "cut_l_shapes": "shelfpick.perception.repairs.l_cuts",
    "split_stepped_faces": "shelfpick.perception.repairs.stepped", "take_stepped_parts": "shelfpick.perception.repairs.stepped",
    "take_bridging_parts": "shelfpick.perception.repairs.bands", "regroup_pieces": "shelfpick.perception.repairs.regroup",
    "absorb_enclosed": "shelfpick.perception.repairs.enclosed",
    "cut_directions": "shelfpick.perception.repairs.border_cut", "complete_cut_face": "shelfpick.perception.repairs.border_cut",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'shelfpick.perception.repairs' has no attribute {name!r}")
