"""Halves of stacked (or side-by-side) cartons of one print, re-cut where the print repeats
(issue 31, the `labels` tuning look).

The segmenter (or the catalogue's seam split) sometimes cuts two stacked cartons of one printed
design down a band: two masks, the left halves and the right halves, each a stack. Each half
measures as a plausible box front, so nothing downstream notices. Together they are one flush
block whose print repeats ACROSS their shared edge, not along it: the two masks on one plane,
joined, are cut by `repeats.repeat_parts` into parts that are not the two masks. That is the
evidence used here, and only where the depth agrees (geometry first):

- the two masks touch and lie on one plane (each one's depth points within `PLANE_TOL` of the
  other's measured face: no step between them, a carton's front is one plane);
- their union (with the unclaimed pixels of the thin gap between them) fills its min-area
  rectangle >= `MIN_FILL` (one flush block, not an L of two faces);
- `repeat_parts` cuts the union (score, peak and print spread as for a merged mask) into parts
  none of which is either mask again (IoU < `SAME_IOU`): a re-cut of the same seam changes nothing;
- every part measures as a box front (the caller's test: on the shelf, >= 10 cm a side).

Two correct cartons of one print side by side re-cut into themselves (the repeat is at their own
seam) and are left alone; plain faces have no print to repeat and are never touched.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from shelfpick.perception.faces import FrontFace
from shelfpick.perception.repairs.measure import plane_dist
from shelfpick.perception.repairs.merged import rect_fill
from shelfpick.perception.repairs.repeats import repeat_parts
from shelfpick.perception.scene import Camera

PLANE_TOL = 0.004   # m: median distance of one mask's depth points to the other's face plane
MIN_FILL = 0.85     # the union fills its min-area rectangle at least this much
SAME_IOU = 0.6      # a part this like one of the two masks is that mask again: nothing to re-cut
GAP_PX = 3          # masks this close touch; the unclaimed pixels between them join the union
MIN_TOUCH_PX = 20   # ... along at least this many pixels


@dataclass(frozen=True, eq=False)
class _Frame:
    """What `plane_dist` reads of a repair context: the depth image and its camera."""

    depth: np.ndarray
    camera: Camera


def regroup_halves(masks: list[np.ndarray], faces: list[FrontFace | None], lab: np.ndarray,
                   depth: np.ndarray, camera: Camera,
                   front: Callable[[np.ndarray], FrontFace | None],
                   ) -> tuple[list[np.ndarray], list[FrontFace | None], list[str]]:
    """(masks, their faces, notes): every pair of touching masks on one plane whose union's print
    repeats across their shared edge replaced by the union's repeat parts (see the module
    docstring). `faces`: the masks' measured faces (None: not measurable); `lab`: the image in
    CIELAB; `front(part)`: the part's face when it is a box front, else None. A pair is tried
    once; parts made here are not re-cut again."""
    masks, faces = [np.asarray(m, bool) for m in masks], list(faces)
    notes: list[str] = []
    made: set[int] = set()
    tried: set[frozenset[int]] = set()
    while True:
        found = _first_pair(masks, faces, lab, _Frame(depth, camera), front, made, tried)
        if found is None:
            return masks, faces, notes
        i, j, parts, pf, axis, score = found
        notes.append(f"masks of {faces[i].size_cm} and {faces[j].size_cm} are halves of {len(parts)} "
                     f"fronts of one print {'stacked' if axis == 0 else 'side by side'} (alike {score:.2f}): "
                     "re-cut into " + " and ".join(f.size_cm for f in pf))
        keep = [k for k in range(len(masks)) if k not in (i, j)]
        masks = [masks[k] for k in keep] + parts
        faces = [faces[k] for k in keep] + pf
        made.update(id(p) for p in parts)


def _first_pair(masks: list[np.ndarray], faces: list[FrontFace | None], lab: np.ndarray, frame: _Frame,
                front: Callable[[np.ndarray], FrontFace | None], made: set[int], tried: set[frozenset[int]]):
    """(i, j, parts, their faces, axis, score) of the first pair that re-cuts, else None."""
    kernel = np.ones((2 * GAP_PX + 1, 2 * GAP_PX + 1), np.uint8)
    near = [cv2.dilate(m.astype(np.uint8), kernel).astype(bool) for m in masks]
    cover = np.sum(masks, axis=0, dtype=np.uint8)       # how many masks claim each pixel
    for i in range(len(masks)):
        for j in range(i + 1, len(masks)):
            key = frozenset((id(masks[i]), id(masks[j])))
            if key in tried or faces[i] is None or faces[j] is None or id(masks[i]) in made \
                    or id(masks[j]) in made or int((near[i] & masks[j]).sum()) < MIN_TOUCH_PX:
                continue
            tried.add(key)
            done = _recut(i, j, masks, faces, near, cover, lab, frame, front)
            if done is not None:
                return (i, j) + done
    return None


def _recut(i: int, j: int, masks: list[np.ndarray], faces: list[FrontFace | None], near: list[np.ndarray],
           cover: np.ndarray, lab: np.ndarray, frame: _Frame, front: Callable[[np.ndarray], FrontFace | None]):
    """(parts, faces, axis, score) when masks i and j re-cut into other box fronts, else None.
    `cover`: how many masks claim each pixel (the gap pixels joined are nobody else's)."""
    a, b = masks[i], masks[j]
    unclaimed = cover <= a.astype(np.uint8) + b.astype(np.uint8)
    union = _core(a | b | (near[i] & near[j] & unclaimed))
    if union is None or rect_fill(union) < MIN_FILL:
        return None
    parts, axis, score = repeat_parts(union, lab)
    if len(parts) < 2 or any(max(_iou(p, a), _iou(p, b)) >= SAME_IOU for p in parts):
        return None
    if plane_dist(faces[i], b, frame) > PLANE_TOL or plane_dist(faces[j], a, frame) > PLANE_TOL:
        return None
    pf = [front(p) for p in parts]
    if any(f is None for f in pf):
        return None
    return parts, pf, axis, score


def _core(union: np.ndarray) -> np.ndarray | None:
    """The union's rows and columns at least half as full as its fullest (a strip of a third face
    along one side of a half is left out, it would skew the print's profile); None when that
    leaves out more than `1 - MIN_FILL` of it (not one flush block)."""
    rows, cols = union.sum(axis=1), union.sum(axis=0)
    core = union & (rows >= 0.5 * rows.max())[:, None] & (cols >= 0.5 * cols.max())[None, :]
    return core if int(core.sum()) >= MIN_FILL * int(union.sum()) else None


def _iou(p: np.ndarray, q: np.ndarray) -> float:
    inter = int(np.count_nonzero(p & q))
    return inter / max(int(np.count_nonzero(p | q)), 1)
