"""One capture in, one scene out: segment, clean masks, measure boxes, make the scene stand.

`perceive` is what the CLI, the console and the benchmark call. It never
raises for an image without boxes (an empty scene and a warning instead);
it raises `PerceptionError` for inputs it cannot use (intrinsics that do not
belong to the image, a distance that is not a distance).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from perception.boxes import (FrontFace, boxes_from_masks, default_front_distance,
                              distance_from_box_size, make_valid, measure_front, planar_depth)
from perception.box_catalogue import Catalogue, apply_catalogue, catalogue_applies
from perception.capture import Capture
from perception.geometry import check_intrinsics, point_map
from perception.masks import border_sides, grow_on_plane, pixel_scale, refine, to_label_image
from perception.overlay import draw_overlay
from perception.repairs.border_cut import complete_cut_face
from perception.scene import Scene, Shelf
from perception.segment import Segmenter, for_capture, load_segmenter, segmenter_name


DEFAULT_CATALOGUE = Catalogue()


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

    def summary(self) -> dict:
        return {"boxes": len(self.scene.boxes), "segmenter": self.segmenter,
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
    from perception.geometry import pose_matrix

    rot, _ = pose_matrix(camera)
    c = float(rot[1, 2])
    if c >= min_cos:
        return ""
    import math

    return (f"the camera looks {math.degrees(math.acos(max(-1.0, min(1.0, c)))):.0f} deg away from the shelf's "
            "depth axis (+y, into the shelf): check its pose.orientation")


# a larger image is perceived at this many pixels (a 3450x2725 photo took 35 s at full size,
# 1920x1080 takes ~1.6 s CPU) and its masks scaled back up
MAX_PIXELS = 1920 * 1080


def _scaled_capture(capture: Capture, s: float) -> Capture:
    """The capture at `s` times its size: RGB by area, depth by nearest pixel (no blending across
    holes or steps), intrinsics scaled about pixel centres."""
    import cv2
    from dataclasses import replace

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
    (the faces' `rect_px` stay in the scaled image)."""
    t0 = time.perf_counter()
    shelf = shelf or Shelf()
    check_intrinsics(capture.camera, capture.shape, origin)
    h, w = capture.shape
    if h * w > max_pixels:
        import cv2
        from dataclasses import replace

        small = _scaled_capture(capture, (max_pixels / (h * w)) ** 0.5)
        res = perceive(small, segmenter, shelf, front_distance=front_distance, box_size=box_size,
                       placeholder=placeholder, origin=origin, catalogue=catalogue,
                       max_pixels=small.shape[0] * small.shape[1])   # once: never scaled again
        labels = cv2.resize(res.masks, (w, h), interpolation=cv2.INTER_NEAREST)
        t = time.perf_counter()
        overlay = draw_overlay(capture.rgb, labels, {b.mask_label: b.id for b in res.scene.boxes if b.mask_label})
        timing = dict(res.timing, overlay=res.timing.get("overlay", 0.0) + time.perf_counter() - t)
        timing["total"] = time.perf_counter() - t0
        note = f"image {w}x{h} perceived at {small.shape[1]}x{small.shape[0]} (over {max_pixels} pixels)"
        return replace(res, scene=replace(res.scene, camera=capture.camera), masks=labels, overlay=overlay,
                       warnings=(note,) + res.warnings, timing=timing)
    timing: dict[str, float] = {}
    warnings: list[str] = []
    camera = capture.camera
    away = looks_away(camera, shelf)
    if away:
        warnings.append(away)
    seg = segmenter if segmenter is not None else load_segmenter(None, "auto")
    seg = for_capture(seg, capture.depth is not None)
    if hasattr(seg, "bind"):
        seg = seg.bind(camera, shelf)  # type: ignore[union-attr]
    depth = capture.depth
    used_distance = None
    if depth is None:
        if front_distance is None and box_size is None:
            front_distance = default_front_distance(camera)
            warnings.append(f"no depth image: assuming a flat front {front_distance:.2f} m from the camera "
                            "(give --front-distance or --box-size)")
        used_distance = front_distance if front_distance is not None else default_front_distance(camera)
        depth = planar_depth(camera, used_distance)
    t = time.perf_counter()
    raw = seg.segment(capture.rgb, depth)
    timing["segment"] = time.perf_counter() - t
    t = time.perf_counter()
    union = np.any(raw, axis=0) if raw else None
    scale = pixel_scale(capture.depth, union)       # 1.0 without depth (the distance is a guess)
    minpx = _min_pixels(capture.shape, scale)
    masks = refine(raw, capture.depth, min_pixels=minpx)
    masks = grow_on_plane(masks, capture.depth, camera, rgb=capture.rgb,
                          allowed=_inside_shelf(capture.depth, camera, shelf))
    catalogue_notes: list[str] = []
    if catalogue is not None and capture.depth is not None and masks:
        masks, measured = apply_catalogue(masks, capture.depth, camera, capture.rgb,
                                          catalogue.scaled(scale).within(shelf.depth), catalogue_notes)
    else:
        measured = None
    timing["masks"] = time.perf_counter() - t
    if capture.depth is None and box_size is not None and front_distance is None and masks:
        used_distance = distance_from_box_size(masks, camera, box_size)
        depth = planar_depth(camera, used_distance)
        warnings.append(f"no depth image: front at {used_distance:.3f} m derived from the box size "
                        f"{box_size[0]:g} x {box_size[1]:g} m")
    t = time.perf_counter()
    if measured is None or depth is not capture.depth:
        measured = [measure_front(m, depth, camera) for m in masks]
    # a face cut by the image border is completed to a type face only in a capture of these types
    types = catalogue if capture.depth is not None and catalogue is not None and masks and \
        catalogue_applies(measured, masks, catalogue.within(shelf.depth)) else None
    measured, completed = _complete_cut_faces(masks, measured, camera, types)
    boxes, masks, faces, w = boxes_from_masks(masks, depth, camera, shelf, placeholder, faces=measured)
    warnings.extend(w)
    warnings.extend(_border_warnings(boxes, masks))
    cut_notes = [f"{b.id}: {completed[id(f)]}" for b, f in zip(boxes, faces) if id(f) in completed]
    boxes, notes = make_valid(boxes, shelf)
    notes = catalogue_notes + cut_notes + notes
    timing["boxes"] = time.perf_counter() - t
    t = time.perf_counter()
    labels = to_label_image(masks, capture.shape)
    overlay = draw_overlay(capture.rgb, labels, {b.mask_label: b.id for b in boxes if b.mask_label})
    timing["overlay"] = time.perf_counter() - t
    if not boxes:
        warnings.append("no boxes found in the image; the scene is empty")
    name = segmenter_name(seg)
    scene = Scene(shelf, tuple(boxes), camera,
                  {"kind": "perception", "segmenter": name, "adjustments": notes})
    timing["total"] = time.perf_counter() - t0
    return Perception(scene, labels, overlay, tuple(warnings), timing, tuple(notes), tuple(faces),
                      name, used_distance, {"pixel_scale": scale})
