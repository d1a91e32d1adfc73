"""One capture in, one scene out: segment, clean masks, measure boxes, make the scene stand.

`perceive` is what the CLI, the console and the benchmark call. It never
raises for an image without boxes (an empty scene and a warning instead);
it raises `PerceptionError` for inputs it cannot use (intrinsics that do not
belong to the image, a distance that is not a distance).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Any

import cv2
import numpy as np

from shelfpick.perception.blas_threads import one_blas_thread
from shelfpick.perception.box_catalogue import Catalogue, apply_catalogue, catalogue_applies
from shelfpick.perception.boxes import (
    CONTRADICTION,
    boxes_from_masks,
    default_front_distance,
    distance_from_box_size,
    flag_contradicted,
    make_valid,
    planar_depth,
)
from shelfpick.perception.capture import Capture
from shelfpick.perception.faces import FrontFace, faces_cached, measure_front
from shelfpick.perception.geometry import check_intrinsics, point_map, points_cached, pose_matrix
from shelfpick.perception.masks import border_sides, grow_on_plane, pixel_scale, refine, to_label_image
from shelfpick.perception.overlay import box_names, draw_overlay, draw_unexplained
from shelfpick.perception.repairs.border_cut import complete_cut_face
from shelfpick.perception.repairs.merged import depth_step_parts
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.perception.segment import Segmenter, for_capture, load_segmenter, segmenter_name
from shelfpick.perception.unexplained import EXPLAIN_TOL, Found, candidates, describe, find_unexplained


DEFAULT_CATALOGUE = Catalogue()
# an unexplained region that is one flat box front no mask covered is perceived as a box (missed_fronts.py)
FIND_MISSED_FRONTS = True


@dataclass(frozen=True, eq=False)
class Perception:
    scene: Scene                       # depth_known false, mask_label k <-> masks == k
    masks: np.ndarray                  # HxW uint16 instance labels
    overlay: np.ndarray                # HxWx3 uint8
    warnings: tuple[str, ...]
    timing: dict[str, float]           # seconds per stage and "total"
    adjustments: tuple[str, ...] = ()  # what make_valid moved
    faces: tuple[FrontFace, ...] = ()
    segmenter: str = ""
    front_distance: float | None = None  # used when the capture had no depth
    extra: dict = field(default_factory=dict)
    unexplained_labels: np.ndarray | None = None  # HxW uint16: label k+1 = scene.unexplained[k]

    def summary(self) -> dict:
        regions = self.scene.unexplained
        return {"boxes": len(self.scene.boxes), "segmenter": self.segmenter,
                "unexplained": None if regions is None else [u.to_json() for u in regions],
                "warnings": list(self.warnings), "adjustments": list(self.adjustments),
                "timing": {k: round(v, 4) for k, v in self.timing.items()},
                "front_distance": self.front_distance,
                "faces": {b.id: f.to_json() for b, f in zip(self.scene.boxes, self.faces)}}


def _min_pixels(shape: tuple[int, int], scale: float = 1.0) -> int:
    """Smallest mask kept (px): 150 at 640x480 and the tuning distance; an area, so it shrinks
    with the square of the pixel scale (`masks.pixel_scale`)."""
    return max(40, int(150 * shape[0] * shape[1] / (640 * 480) * scale * scale))


def _inside_shelf(depth: np.ndarray | None, camera, shelf: Shelf, margin: float = 0.004) -> np.ndarray | None:
    """Pixels whose point lies inside the shelf volume (the shelf's own boards are not boxes)."""
    if depth is None:
        return None
    p = point_map(camera, depth)
    return ((p[..., 2] > margin) & (np.abs(p[..., 0]) < shelf.width / 2 - margin)
            & (p[..., 1] < shelf.depth - margin) & (p[..., 2] < shelf.height - margin))


def _complete_cut_faces(masks: list[np.ndarray], faces: list[FrontFace | None], camera,
                        catalogue: Catalogue | None) -> tuple[list[FrontFace | None], dict[int, str]]:
    """Faces cut by the image border, completed to a type face where the catalogue explains
    them (else kept at least as seen, never dropped for being thin); id(new face) -> what was done."""
    out = list(faces)
    done: dict[int, str] = {}
    for i, (m, f) in enumerate(zip(masks, faces)):
        sides = border_sides(m)
        if f is None or not sides:
            continue
        g, cut, how = complete_cut_face(f, m, camera, catalogue, sides)
        out[i] = g
        if how is not None:
            what = "the type face" if how == "type" else "at least"
            done[id(g)] = (f"face cut by the {'/'.join(sides)} image border, seen {f.size_cm}, "
                           f"taken as {what} {g.size_cm}")
    return out, done


def _border_warnings(boxes: list, masks: list[np.ndarray]) -> list[str]:
    """One warning per image border (top, left, right) that perceived faces run into."""
    by_side: dict[str, list[str]] = {}
    for b, m in zip(boxes, masks):
        for side in border_sides(m):
            by_side.setdefault(side, []).append(b.id)
    where = {"top": "above", "left": "left of", "right": "right of"}
    return [f"{', '.join(ids)} touch{'es' if len(ids) == 1 else ''} the {side} image border: boxes may be cut "
            f"off or lie {where[side]} the view; the scene may be incomplete there"
            for side, ids in by_side.items() if side in where]


def looks_away(camera, shelf: Shelf, min_cos: float = 0.2) -> str:
    """A warning ('' if none) when the camera's optical axis does not point into the shelf
    (shelf +y): a pose with a sign or axis mixed up sees no shelf, and the scene comes out
    empty or nonsensical; the user should hear why."""
    rot, _ = pose_matrix(camera)
    c = float(rot[1, 2])
    if c >= min_cos:
        return ""
    return (f"the camera looks {math.degrees(math.acos(max(-1.0, min(1.0, c)))):.0f} deg away from the shelf's "
            "depth axis (+y, into the shelf): check its pose.orientation")


# a larger image is perceived at this many pixels (a 3450x2725 photo took 35 s at full size,
# 1920x1080 takes ~1.6 s CPU) and its masks scaled back up
MAX_PIXELS = 1920 * 1080


def _scaled_capture(capture: Capture, s: float) -> Capture:
    """The capture at `s` times its size: RGB by area, depth by nearest pixel (no blending across
    holes or steps), intrinsics scaled about pixel centres."""
    h, w = capture.shape
    sw, sh = max(1, int(w * s)), max(1, int(h * s))
    kx, ky = sw / w, sh / h
    c = capture.camera
    cam = replace(c, width=sw, height=sh, fx=c.fx * kx, fy=c.fy * ky,
                  cx=(c.cx + 0.5) * kx - 0.5, cy=(c.cy + 0.5) * ky - 0.5)
    rgb = cv2.resize(capture.rgb, (sw, sh), interpolation=cv2.INTER_AREA)
    depth = None if capture.depth is None else \
        cv2.resize(capture.depth, (sw, sh), interpolation=cv2.INTER_NEAREST)
    return Capture(rgb, depth, cam)


def perceive(capture: Capture, segmenter: Segmenter | None = None, shelf: Shelf | None = None, *,
             front_distance: float | None = None, box_size: tuple[float, float] | None = None,
             placeholder: float = 0.25, origin: str = "camera",
             catalogue: Catalogue | None = DEFAULT_CATALOGUE, max_pixels: int = MAX_PIXELS) -> Perception:
    """The scene seen in `capture` (see module docstring). `catalogue`: the box types a face
    may be (joins pieces and splits merged faces only where it explains them); None: no types.
    An image over `max_pixels` is perceived scaled down; its masks and overlay are full size
    (the faces' `rect_px` stay in the scaled image). Runs with one BLAS thread (`blas_threads`), the
    frame's points computed once (`geometry.points_cached`), each mask's face measured once
    (`faces.faces_cached`). A process that perceives frame after frame may keep freed arrays'
    pages (`heap_pages.keep_freed_pages`, process-wide): its caller's choice, the CLI's and the
    console's, not this function's."""
    with one_blas_thread(), points_cached(), faces_cached():
        return _perceive(capture, segmenter, shelf, front_distance=front_distance, box_size=box_size,
                         placeholder=placeholder, origin=origin, catalogue=catalogue, max_pixels=max_pixels)


def _perceive(capture: Capture, segmenter: Segmenter | None, shelf: Shelf | None, *,
              front_distance: float | None, box_size: tuple[float, float] | None, placeholder: float,
              origin: str, catalogue: Catalogue | None, max_pixels: int) -> Perception:
    """`perceive`'s work (see there)."""
    t0 = time.perf_counter()
    shelf = shelf or Shelf()
    check_intrinsics(capture.camera, capture.shape, origin)
    h, w = capture.shape
    if h * w > max_pixels:
        return _perceive_scaled(capture, max_pixels, t0, segmenter=segmenter, shelf=shelf,
                                front_distance=front_distance, box_size=box_size, placeholder=placeholder,
                                origin=origin, catalogue=catalogue)
    timing: dict[str, float] = {}
    warnings: list[str] = []
    camera = capture.camera
    away = looks_away(camera, shelf)
    if away:
        warnings.append(away)
    seg = _bound_segmenter(segmenter, capture, shelf)
    depth, used_distance, flat = _stand_in_depth(capture, front_distance, box_size)
    if flat:
        warnings.append(flat)
    masks, measured, scale, catalogue_notes = _segmented(seg, capture, depth, shelf, catalogue, timing)
    if capture.depth is None and box_size is not None and front_distance is None and masks:
        used_distance, depth, said_distance = _distance_from_size(masks, camera, box_size)
        warnings.append(said_distance)
    boxes, labels, faces, notes, found = _explained_boxes(masks, measured, depth, capture, shelf, catalogue,
                                                          placeholder, timing, warnings)
    notes = catalogue_notes + notes
    if found is not None and found.regions:    # first: what the shelf holds that no box explains
        warnings.insert(0, describe(found.regions))
    overlay = _overlay(capture, labels, boxes, found, timing)
    if not boxes:
        warnings.append("no boxes found in the image; the scene is empty")
    name = segmenter_name(seg)
    scene = Scene(shelf, tuple(boxes), camera,
                  {"kind": "perception", "segmenter": name, "adjustments": notes},
                  None if found is None else found.regions)
    timing["total"] = time.perf_counter() - t0
    return Perception(scene, labels, overlay, tuple(warnings), timing, tuple(notes), tuple(faces),
                      name, used_distance, {"pixel_scale": scale},
                      None if found is None else found.labels)


def _bound_segmenter(segmenter: Segmenter | None, capture: Capture, shelf: Shelf) -> Segmenter:
    """The segmenter this capture is segmented with: the one given (else the automatic choice),
    the variant for a capture with or without depth, bound to its camera and shelf if it can be."""
    seg = segmenter if segmenter is not None else load_segmenter(None, "auto")
    seg = for_capture(seg, capture.depth is not None)
    if hasattr(seg, "bind"):
        seg = seg.bind(capture.camera, shelf)  # type: ignore[union-attr]
    return seg


def _segmented(seg: Segmenter, capture: Capture, depth: np.ndarray, shelf: Shelf, catalogue: Catalogue | None,
               timing: dict[str, float]) -> tuple[list[np.ndarray], Any, float, list[str]]:
    """The segmenter's masks, cleaned (`_clean_masks`): (masks, measured faces, pixel scale, the
    catalogue's notes); each stage's seconds go into `timing`."""
    t = time.perf_counter()
    raw = seg.segment(capture.rgb, depth)
    timing["segment"] = time.perf_counter() - t
    t = time.perf_counter()
    cleaned = _clean_masks(raw, capture, shelf, catalogue)
    timing["masks"] = time.perf_counter() - t
    return cleaned


def _distance_from_size(masks: list[np.ndarray], camera, box_size: tuple[float, float]
                        ) -> tuple[float, np.ndarray, str]:
    """No depth image, but the boxes' size: (front distance, the flat depth at it, the warning that
    says where it came from)."""
    used_distance = distance_from_box_size(masks, camera, box_size)
    depth = planar_depth(camera, used_distance)
    return used_distance, depth, (f"no depth image: front at {used_distance:.3f} m derived from the box size "
                                  f"{box_size[0]:g} x {box_size[1]:g} m")


def _explained_boxes(masks: list[np.ndarray], measured: Any, depth: np.ndarray, capture: Capture, shelf: Shelf,
                     catalogue: Catalogue | None, placeholder: float, timing: dict[str, float],
                     warnings: list[str]) -> tuple[list[Box], np.ndarray, list, list[str], Found | None]:
    """The boxes of the masks, made valid, and what no box explains: (boxes, label image, faces,
    notes, unexplained found); what the user must hear is added to `warnings`."""
    t = time.perf_counter()
    offered = masks
    boxes, masks, faces, said, notes = _boxes(masks, measured, depth, capture, shelf, catalogue, placeholder)
    timing["boxes"] = time.perf_counter() - t
    labels = to_label_image(masks, capture.shape)
    boxes, found, valid_notes = _valid_and_explained(boxes, capture, shelf, labels, offered, masks, timing)
    missed = _missed(found, boxes, capture, shelf) if FIND_MISSED_FRONTS else []
    if missed:      # fronts the segmenter missed, seen in the matter: perceived again with them as masks
        t = time.perf_counter()
        offered = list(offered) + [m.mask for m in missed]
        again = None if measured is None else list(measured) + [m.face for m in missed]
        boxes, masks, faces, said, notes = _boxes(offered, again, depth, capture, shelf, catalogue, placeholder)
        notes = [m.note for m in missed] + notes
        timing["boxes"] += time.perf_counter() - t
        labels = to_label_image(masks, capture.shape)
        boxes, found, valid_notes = _valid_and_explained(boxes, capture, shelf, labels, offered, masks, timing)
    warnings.extend(said)
    warnings += [n for n in valid_notes if CONTRADICTION in n]   # faces that cannot all be right: said, not only moved
    return boxes, labels, faces, notes + valid_notes, found


def _missed(found: Found | None, boxes: list[Box], capture: Capture, shelf: Shelf) -> list:
    """The unexplained regions that are box fronts the segmenter missed (`missed_fronts`)."""
    if found is None or not found.regions:
        return []
    from shelfpick.perception.missed_fronts import missed_fronts

    return missed_fronts([u.id for u in found.regions], found.labels, boxes, capture.depth, capture.camera, shelf)


def _overlay(capture: Capture, labels: np.ndarray, boxes: list[Box], found: Found | None,
             timing: dict[str, float]) -> np.ndarray:
    """The masks, rectangles and box ids (' ?' on a doubted face) over the RGB, with the regions
    no box explains; its seconds go into `timing`."""
    t = time.perf_counter()
    overlay = draw_overlay(capture.rgb, labels, box_names(boxes))
    if found is not None and found.regions:
        overlay = draw_unexplained(overlay, found.labels, [u.id for u in found.regions])
    timing["overlay"] = time.perf_counter() - t
    return overlay


def _perceive_scaled(capture: Capture, max_pixels: int, t0: float, **kw: Any) -> Perception:
    """`perceive` of the capture scaled down to `max_pixels`, with its labels and overlay
    scaled back up to the full image and a warning that says so."""
    h, w = capture.shape
    small = _scaled_capture(capture, (max_pixels / (h * w)) ** 0.5)
    res = perceive(small, **kw, max_pixels=small.shape[0] * small.shape[1])   # once: never scaled again
    labels = cv2.resize(res.masks, (w, h), interpolation=cv2.INTER_NEAREST)
    t = time.perf_counter()
    overlay = draw_overlay(capture.rgb, labels, box_names(res.scene.boxes))     # ' ?' as unscaled
    regions = res.unexplained_labels
    if regions is not None:
        regions = cv2.resize(regions, (w, h), interpolation=cv2.INTER_NEAREST)
        if res.scene.unexplained:
            overlay = draw_unexplained(overlay, regions, [u.id for u in res.scene.unexplained])
    timing = dict(res.timing, overlay=res.timing.get("overlay", 0.0) + time.perf_counter() - t)
    timing["total"] = time.perf_counter() - t0
    note = f"image {w}x{h} perceived at {small.shape[1]}x{small.shape[0]} (over {max_pixels} pixels)"
    return replace(res, scene=replace(res.scene, camera=capture.camera), masks=labels, overlay=overlay,
                   warnings=(note,) + res.warnings, timing=timing, unexplained_labels=regions)


def _stand_in_depth(capture: Capture, front_distance: float | None,
                    box_size: tuple[float, float] | None) -> tuple[np.ndarray, float | None, str]:
    """(depth to segment with, the flat front's distance or None, a warning or ''): the
    capture's own depth, or without one a flat front at `front_distance` (or where the
    camera's axis meets the shelf front when neither it nor `box_size` is given)."""
    if capture.depth is not None:
        return capture.depth, None, ""
    flat = ""
    if front_distance is None and box_size is None:
        front_distance = default_front_distance(capture.camera)
        flat = (f"no depth image: assuming a flat front {front_distance:.2f} m from the camera "
                "(give --front-distance or --box-size)")
    used = front_distance if front_distance is not None else default_front_distance(capture.camera)
    return planar_depth(capture.camera, used), used, flat


def _clean_masks(raw: list[np.ndarray], capture: Capture, shelf: Shelf, catalogue: Catalogue | None,
                 ) -> tuple[list[np.ndarray], list[FrontFace | None] | None, float, list[str]]:
    """(masks, their faces or None if not measured yet, pixel scale, catalogue notes): the
    segmenter's masks refined, grown onto their planes and repaired by the catalogue (RGB-D)."""
    union = np.any(raw, axis=0) if raw else None
    scale = pixel_scale(capture.depth, union)       # 1.0 without depth (the distance is a guess)
    minpx = _min_pixels(capture.shape, scale)
    masks = refine(raw, capture.depth, min_pixels=minpx)
    masks = grow_on_plane(masks, capture.depth, capture.camera, rgb=capture.rgb,
                          allowed=_inside_shelf(capture.depth, capture.camera, shelf))
    cut: list[str] = []
    lab = _lab(capture) if capture.depth is not None and masks else None   # both print repairs read it
    if lab is not None:
        masks, cut = _depth_seams(masks, capture.depth)
        masks, repeats = _repeat_cuts(masks, capture, shelf, lab)
        cut += repeats
    measured: list[FrontFace | None] | None = None
    if catalogue is not None and capture.depth is not None and masks:
        masks, measured, notes = apply_catalogue(masks, capture.depth, capture.camera, capture.rgb,
                                                 catalogue.scaled(scale).within(shelf.depth))
        cut += notes
    if capture.depth is not None and len(masks) > 1:
        masks, measured, halves = _regroup_halves(masks, measured, capture, shelf, lab)
        cut += halves
    return masks, measured, scale, cut


def _depth_seams(masks: list[np.ndarray], depth: np.ndarray) -> tuple[list[np.ndarray], list[str]]:
    """(masks, notes): each seam between two stacked masks moved onto the depth step between the
    cartons' fronts where it lies off it (`repairs.stacked_seams`: a print band taken for the
    seam); before the print repairs, which then see whole cartons."""
    from shelfpick.perception.repairs.stacked_seams import depth_seams

    masks, moves = depth_seams(masks, depth)
    return masks, [f"the seam between masks {u + 1} and {lo + 1} moved {abs(d)} px {'down' if d > 0 else 'up'} "
                   "onto the depth step between their fronts" for u, lo, d in moves]


def _lab(capture: Capture) -> np.ndarray:
    """The capture's image in CIELAB (what the print repairs compare)."""
    return cv2.cvtColor(capture.rgb.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)


def _regroup_halves(masks: list[np.ndarray], measured: list[FrontFace | None] | None, capture: Capture,
                    shelf: Shelf, lab: np.ndarray | None = None,
                    ) -> tuple[list[np.ndarray], list[FrontFace | None], list[str]]:
    """(masks, faces, notes): two masks on one plane that are halves of cartons of one print
    (a stack cut down a band) re-cut where the print repeats (`repairs.halves`); after the
    catalogue, whose seam split can make such halves too."""
    from shelfpick.perception.repairs.halves import regroup_halves

    depth, camera = capture.depth, capture.camera
    faces = measured if measured is not None else [measure_front(m, depth, camera) for m in masks]
    lab = _lab(capture) if lab is None else lab
    return regroup_halves(masks, faces, lab, depth, camera, lambda p: _repeat_front(p, capture, shelf))


def _repeat_front(part: np.ndarray, capture: Capture, shelf: Shelf) -> FrontFace | None:
    """The part's face when it measures as a box front at least `REPEAT_MIN_SIDE` a side (a
    part of a repeat cut), else None."""
    from shelfpick.perception.boxes import not_a_face, not_a_front
    from shelfpick.perception.repairs.repeats import REPEAT_MIN_SIDE

    q = measure_front(part, capture.depth, capture.camera)
    if q is None or not_a_front(q, shelf) or not_a_face(q, part) or min(q.width, q.height) < REPEAT_MIN_SIDE:
        return None
    return q


def _repeat_cuts(masks: list[np.ndarray], capture: Capture, shelf: Shelf,
                 lab: np.ndarray | None = None) -> tuple[list[np.ndarray], list[str]]:
    """(masks, notes): a mask that is cartons of one print, stacked or side by side, cut where
    the print repeats (`repairs.repeats`), kept only when every part measures as a box front
    (RGB-D only: the parts are measured on the depth). A mask that does not repeat as a whole is
    tried again front by front, parted at its depth steps (`_stepped_repeat_cuts`). Runs before
    the catalogue, whose joins and splits then see the cut masks."""
    lab = _lab(capture) if lab is None else lab
    out: list[np.ndarray] = []
    notes: list[str] = []
    for i, m in enumerate(masks):
        cut = _repeat_cut(m, capture, shelf, lab)
        if cut is not None:
            notes.append(f"mask {i + 1} is {cut[1]}")
            out.extend(cut[0])
            continue
        parts, words = _stepped_repeat_cuts(m, capture, shelf, lab)
        if words:
            notes.append(f"mask {i + 1} parted at a depth step into {len(words)} fronts, then " + "; ".join(words))
        out.extend(parts)
    return out, notes


def _stepped_repeat_cuts(m: np.ndarray, capture: Capture, shelf: Shelf,
                         lab: np.ndarray) -> tuple[list[np.ndarray], list[str]]:
    """(masks, words): fronts at two depths in one mask (a stack of one print beside deeper
    cartons, an L or a block) repeat in neither direction as one; each front, parted at the depth
    step as `boxes_from_masks` would part it later, may (`labels` 31028: four cubes stacked in one
    81 cm mask with the wide cartons beside them). ([m], []) when no front is cut."""
    if capture.depth is None:
        return [m], []
    steps = depth_step_parts(m, capture.depth, _min_pixels(capture.shape))
    cuts = [_repeat_cut(p, capture, shelf, lab) for p in steps] if len(steps) > 1 else []
    if all(c is None for c in cuts):
        return [m], []
    out: list[np.ndarray] = []
    for p, c in zip(steps, cuts):
        out.extend([p] if c is None else c[0])
    return out, [f"front {k + 1} is {c[1]}" if c else f"front {k + 1} left whole" for k, c in enumerate(cuts)]


def _repeat_cut(m: np.ndarray, capture: Capture, shelf: Shelf, lab: np.ndarray) -> tuple[list[np.ndarray], str] | None:
    """(parts, words) of mask `m` cut where its print repeats, every part a box front; else None."""
    from shelfpick.perception.repairs.repeats import repeat_parts

    parts, axis, score = repeat_parts(m, lab)
    if len(parts) < 2:
        return None
    pf = [_repeat_front(p, capture, shelf) for p in parts]
    if any(q is None for q in pf):
        return None
    return parts, (f"{len(parts)} fronts of one print {'stacked' if axis == 0 else 'side by side'} "
                   f"(alike {score:.2f}): cut into " + " and ".join(q.size_cm for q in pf if q is not None))


def _boxes(masks: list[np.ndarray], measured: list[FrontFace | None] | None, depth: np.ndarray,
           capture: Capture, shelf: Shelf, catalogue: Catalogue | None, placeholder: float,
           ) -> tuple[list, list[np.ndarray], list[FrontFace], list[str], list[str]]:
    """(boxes, their masks, their faces, warnings, notes): faces measured (unless the catalogue
    did on this depth), border-cut ones completed, boxes built (`_valid_and_explained` then makes
    them valid, with the unexplained matter as supports)."""
    camera = capture.camera
    if measured is None or depth is not capture.depth:
        measured = [measure_front(m, depth, camera) for m in masks]
    # a face cut by the image border is completed to a type face only in a capture of these types
    types = catalogue if capture.depth is not None and catalogue is not None and masks and \
        catalogue_applies(measured, masks, catalogue.within(shelf.depth)) else None
    measured, completed = _complete_cut_faces(masks, measured, camera, types)
    # masks that are two boxes (a depth step, an L outline) are cut by geometry: real depth only
    split = _min_pixels(capture.shape) if capture.depth is not None else None
    boxes, masks, faces, warnings = boxes_from_masks(masks, depth, camera, shelf, placeholder, faces=measured,
                                                     split_min_px=split)
    warnings.extend(_border_warnings(boxes, masks))
    cut_notes = [f"{b.id}: {completed[id(f)]}" for b, f in zip(boxes, faces) if id(f) in completed]
    return boxes, masks, faces, warnings, cut_notes


def _valid_and_explained(boxes: list[Box], capture: Capture, shelf: Shelf, labels: np.ndarray,
                         offered: list[np.ndarray], kept: list[np.ndarray], timing: dict[str, float],
                         ) -> tuple[list[Box], Found | None, list[str]]:
    """(boxes made valid, those a contradiction names marked `perceived.contradicted`; the
    unexplained matter or None without depth; what make_valid changed).

    The matter is found first, on the boxes as measured, and stands in as supports while
    `make_valid` rests the boxes: a box on a support the segmenter missed (two merged boxes
    refused as no box front, issue 31) stays where the camera saw it instead of being dropped
    into the hole. It is found again when a box still moved (>= 1 cm): the depth there is then
    matter the final boxes do not explain."""
    t = time.perf_counter()
    found = None
    if capture.depth is not None:    # without a depth image nobody knows where matter is
        ids = {id(m) for m in kept}
        dropped = [(i + 1, m) for i, m in enumerate(offered) if id(m) not in ids]
        cand = candidates(capture.depth, capture.camera, shelf)
        found = find_unexplained(capture.depth, capture.camera, shelf, boxes, labels, dropped, cand)
    timing["unexplained"] = time.perf_counter() - t
    t = time.perf_counter()
    props = _supports(found.regions if found is not None else (), shelf)
    valid, notes = make_valid(list(boxes) + props, shelf)
    valid = valid[:len(boxes)]
    notes = [n for n in notes if "~" not in n]          # what moved the stand-ins is nobody's business
    timing["boxes"] = timing.get("boxes", 0.0) + time.perf_counter() - t
    moved = max((math.dist(a.position, b.position) for a, b in zip(boxes, valid)), default=0.0)
    if found is not None and moved >= 0.01:
        t = time.perf_counter()
        found = find_unexplained(capture.depth, capture.camera, shelf, valid, labels, dropped, cand)
        timing["unexplained"] += time.perf_counter() - t
    return flag_contradicted(valid, notes), found, notes     # faces that cannot all be right, marked for planning


def _supports(regions, shelf: Shelf) -> list[Box]:
    """Unexplained matter as boxes `make_valid` may rest others on: each column of seen surface
    from its nearest point to the back wall, from its bottom (less the band the floor or the box
    under it explains) up to its top plus the band the box above explains (`EXPLAIN_TOL`), 5 mm
    narrower each side so it pushes no neighbour aside. Ids start with '~'."""
    out = []
    for u in regions:
        for i, (x0, x1, z0, z1, y) in enumerate(u.columns):
            lo, hi = max(0.0, z0 - EXPLAIN_TOL), z1 + EXPLAIN_TOL
            w, d = x1 - x0 - 0.01, shelf.depth - y
            if w < 0.005 or d < 0.005 or hi - lo < 0.005:
                continue
            out.append(Box(f"~{u.id}.{i}", (w, d, hi - lo), ((x0 + x1) / 2, y + d / 2, (lo + hi) / 2)))
    return out
