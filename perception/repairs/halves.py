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

A mask may also be the halves of two cartons at once: a strip down the band of a stack whose
other halves are masks of their own (`labels` 31028: the left 20 cm of two 50 cm cartons in one
mask, their right 30 cm in two). No pair of the three is a flush block; the strip and the two or
more masks along one side of it, each within the strip's extent, are tried together the same way
(`_first_group`, after every pair), a part counting as a mask again only when it is that mask
(IoU >= `SAME_IOU_GROUP`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import cv2
import numpy as np

from shelfpick.perception.faces import FrontFace, face_axes
from shelfpick.perception.geometry import backproject
from shelfpick.perception.pixels import nonzero
from shelfpick.perception.repairs.merged import rect_fill
from shelfpick.perception.repairs.repeats import repeat_parts
from shelfpick.perception.scene import Camera

PLANE_TOL = 0.004   # m: median distance of one mask's depth points to the other's face plane
MIN_FILL = 0.85     # the union fills its min-area rectangle at least this much
SAME_IOU = 0.6      # a part this like one of the two masks is that mask again: nothing to re-cut
SAME_IOU_GROUP = 0.95  # ... of a mask and the two or more beside it: only a part that IS one of them (a
#                        carton whose left fifth was the strip is 0.8 like its right four fifths)
GAP_PX = 3          # masks this close touch; the unclaimed pixels between them join the union
MIN_TOUCH_PX = 20   # ... along at least this many pixels


@dataclass(frozen=True, eq=False)
class _Frame:
    """The depth image and its camera (where the masks' depth points are)."""

    depth: np.ndarray
    camera: Camera


@dataclass(eq=False)
class _Ctx:
    """One search for a pair or group to re-cut: the masks as they stand, and what both searches
    read of them (bounding boxes, dilations, how many masks claim each pixel), computed once."""

    masks: list[np.ndarray]
    faces: list[FrontFace | None]
    lab: np.ndarray
    frame: _Frame
    front: Callable[[np.ndarray], FrontFace | None]
    made: set[int]
    tried: set[frozenset[int]]

    def __post_init__(self) -> None:
        self.boxes = [_bbox(m) for m in self.masks]
        self.near = [_near(m, b) for m, b in zip(self.masks, self.boxes)]
        self.cover = _cover(self.masks, self.boxes)


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
        ctx = _Ctx(masks, faces, lab, _Frame(depth, camera), front, made, tried)
        found = _first_pair(ctx) or _first_group(ctx)
        if found is None:
            return masks, faces, notes
        i, js, parts, pf, axis, score = found
        notes.append(f"masks of {' and '.join(faces[k].size_cm for k in (i, *js))} are halves of {len(parts)} "  # type: ignore[union-attr]
                     f"fronts of one print {'stacked' if axis == 0 else 'side by side'} (alike {score:.2f}): "
                     "re-cut into " + " and ".join(f.size_cm for f in pf))
        keep = [k for k in range(len(masks)) if k != i and k not in js]
        masks = [masks[k] for k in keep] + parts
        faces = [faces[k] for k in keep] + pf
        made.update(id(p) for p in parts)


def _first_pair(c: _Ctx):
    """(i, [j], parts, their faces, axis, score) of the first pair that re-cuts, else None."""
    masks, faces, boxes, near = c.masks, c.faces, c.boxes, c.near
    for i in range(len(masks)):
        for j in range(i + 1, len(masks)):
            key = frozenset((id(masks[i]), id(masks[j])))
            if key in c.tried or faces[i] is None or faces[j] is None or id(masks[i]) in c.made \
                    or id(masks[j]) in c.made or not _overlap(boxes[i], boxes[j]) \
                    or _touch(near[i], masks[j], boxes[i], boxes[j]) < MIN_TOUCH_PX:
                continue
            c.tried.add(key)
            done = _recut([i, j], c)
            if done is not None:
                return (i, [j]) + done
    return None


def _recut(idx: list[int], c: _Ctx):
    """(parts, faces, axis, score) when the masks `idx` (the first one touching each of the others)
    re-cut into other box fronts, else None. The gap pixels joined are nobody else's (`c.cover`).
    Works on the group's bounding box; the parts come back full size."""
    masks, faces, boxes, near, cover, frame = c.masks, c.faces, c.boxes, c.near, c.cover, c.frame
    i, rest = idx[0], idx[1:]
    box = (slice(max(min(boxes[k][0] for k in idx) - GAP_PX, 0), max(boxes[k][1] for k in idx) + GAP_PX),
           slice(max(min(boxes[k][2] for k in idx) - GAP_PX, 0), max(boxes[k][3] for k in idx) + GAP_PX))
    crops = [masks[k][box] for k in idx]
    claimed = np.sum([c.astype(np.uint8) for c in crops], axis=0)
    gap = near[i][box] & np.logical_or.reduce([near[k][box] for k in rest]) & (cover[box] <= claimed)
    union = _core(np.logical_or.reduce(crops) | gap)
    if union is None or rect_fill(union) < MIN_FILL:
        return None
    if any(_off_plane(faces[i], masks[k][box], box, frame) > PLANE_TOL
           or _off_plane(faces[k], crops[0], box, frame) > PLANE_TOL for k in rest):
        return None                  # a depth step (or a turn) between them: two fronts
    cut, axis, score = repeat_parts(union, c.lab[box])
    same = SAME_IOU if len(idx) == 2 else SAME_IOU_GROUP
    if len(cut) < 2 or any(_iou(p, c) >= same for p in cut for c in crops):
        return None
    parts = []
    for p in cut:
        full = np.zeros_like(masks[i])
        full[box] = p
        parts.append(full)
    pf = [c.front(p) for p in parts]
    if any(f is None for f in pf):
        return None
    return parts, pf, axis, score


def _first_group(c: _Ctx):
    """(i, [j, ...], parts, their faces, axis, score) of the first mask that re-cuts with the two or
    more masks it touches along one side, each within its extent across that side (a strip that
    is the left halves of two stacked cartons, beside their two right halves: `labels` 31028's
    50 cm cartons cut down their band), else None."""
    masks, boxes, near = c.masks, c.boxes, c.near
    free = [k for k in range(len(masks)) if c.faces[k] is not None and id(masks[k]) not in c.made]
    for i in free:
        touching = [j for j in free if j != i and _overlap(boxes[i], boxes[j])
                    and _touch(near[i], masks[j], boxes[i], boxes[j]) >= MIN_TOUCH_PX]
        for group in _one_side(i, touching, boxes):
            key = frozenset(id(masks[k]) for k in (i, *group))
            if key in c.tried:
                continue
            c.tried.add(key)
            done = _recut([i, *group], c)
            if done is not None:
                return (i, group) + done
    return None


def _one_side(i: int, touching: list[int], boxes: list[tuple[int, int, int, int]]) -> list[list[int]]:
    """The groups of two or more of `touching` that lie on one side of mask i (left, right, above,
    below), each within i's extent along that side (GAP_PX to spare)."""
    y0, y1, x0, x1 = boxes[i]
    cy, cx = (y0 + y1) / 2, (x0 + x1) / 2
    rows = [j for j in touching if boxes[j][0] >= y0 - 2 * GAP_PX and boxes[j][1] <= y1 + 2 * GAP_PX]
    cols = [j for j in touching if boxes[j][2] >= x0 - 2 * GAP_PX and boxes[j][3] <= x1 + 2 * GAP_PX]
    sides = [[j for j in rows if (boxes[j][2] + boxes[j][3]) / 2 > cx], [j for j in rows if (boxes[j][2] + boxes[j][3]) / 2 < cx],
             [j for j in cols if (boxes[j][0] + boxes[j][1]) / 2 > cy], [j for j in cols if (boxes[j][0] + boxes[j][1]) / 2 < cy]]
    return [g for g in sides if len(g) >= 2]


def _off_plane(face: FrontFace, mask: np.ndarray, box: tuple[slice, slice], frame: _Frame,
               most: int = 2000) -> float:
    """Median distance (m) of the depth points of `mask` (cropped to `box`) to the plane of `face`."""
    depth = frame.depth[box]
    ys, xs = nonzero(mask & np.isfinite(depth) & (depth > 0))
    if len(xs) < 10:
        return float("inf")
    step = len(xs) // most + 1
    ys, xs = ys[::step], xs[::step]
    z = depth[ys, xs].astype(np.float64)
    p = backproject(frame.camera, (xs + box[1].start).astype(np.float64), (ys + box[0].start).astype(np.float64), z)
    return float(np.median(np.abs((p - np.asarray(face.center)) @ face_axes(face)[:, 1])))


def _bbox(m: np.ndarray) -> tuple[int, int, int, int]:
    """(first row, last row + 1, first column, last column + 1) of a mask; (0, 0, 0, 0) if empty."""
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    if not len(rows):
        return 0, 0, 0, 0
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _grown(b: tuple[int, int, int, int]) -> tuple[slice, slice]:
    """A `_bbox` grown by GAP_PX (cut at the image's top and left: slicing cuts the rest)."""
    return slice(max(b[0] - GAP_PX, 0), b[1] + GAP_PX), slice(max(b[2] - GAP_PX, 0), b[3] + GAP_PX)


def _near(mask: np.ndarray, box: tuple[int, int, int, int]) -> np.ndarray:
    """The mask dilated by a (2 GAP_PX + 1) square, dilated within its box grown by GAP_PX
    (`box`: its `_bbox`): outside that the whole frame's dilation is empty and inside it sees
    the same pixels, so the same mask, without dilating the whole frame a mask at a time."""
    win = _grown(box)
    out = np.zeros(mask.shape, bool)
    kernel = np.ones((2 * GAP_PX + 1, 2 * GAP_PX + 1), np.uint8)
    out[win] = cv2.dilate(mask[win].astype(np.uint8), kernel).astype(bool)
    return out


def _cover(masks: list[np.ndarray], boxes: list[tuple[int, int, int, int]]) -> np.ndarray:
    """How many masks claim each pixel: `np.sum(masks, axis=0, dtype=np.uint8)`, each mask added
    in its box (`boxes`: their `_bbox`) instead of stacking them all."""
    cover = np.zeros(masks[0].shape if masks else (0, 0), np.uint8)
    for m, (y0, y1, x0, x1) in zip(masks, boxes):
        cover[y0:y1, x0:x1] += m[y0:y1, x0:x1]
    return cover


def _touch(near: np.ndarray, mask: np.ndarray, near_box: tuple[int, int, int, int],
           box: tuple[int, int, int, int]) -> int:
    """`int((near & mask).sum())`, counted where the two can both be set: `near` (a `_near`) in
    its mask's box grown by GAP_PX, `mask` in its own box."""
    rows, cols = _grown(near_box)
    win = (slice(max(rows.start, box[0]), min(rows.stop, box[1])), slice(max(cols.start, box[2]), min(cols.stop, box[3])))
    return int(np.count_nonzero(near[win] & mask[win]))


def _overlap(p: tuple[int, int, int, int], q: tuple[int, int, int, int]) -> bool:
    """Whether two bounding boxes, grown by GAP_PX, overlap."""
    return p[0] - GAP_PX < q[1] and q[0] - GAP_PX < p[1] and p[2] - GAP_PX < q[3] and q[2] - GAP_PX < p[3]


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
