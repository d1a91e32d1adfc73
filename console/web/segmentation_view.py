"""The segmentation image, with the faces a plan set aside drawn as unexplained matter (issue 31).

Perception draws its overlay once, at capture, before any plan: every mask a box. When the
planner then sets faces aside (planning/set_aside.py: faces no sample world can hold), the 3D
view draws them as grey matter in place of their boxes; this redraws the overlay the same way
from the capture's label images, so the two views tell the operator one story: the set-aside
masks greyed, hatched and named `aside-b6?`, like the regions perception could not explain.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, AbstractSet, Any, Mapping, Sequence

import numpy as np

from shelfpick.perception.overlay import box_names, draw_overlay, draw_unexplained
from shelfpick.perception.scene import Scene

if TYPE_CHECKING:  # pragma: no cover
    from shelfpick.planning.plan import Plan


def draw_segmentation(rgb: np.ndarray, labels: np.ndarray, matter: np.ndarray | None, scene: Scene,
                      aside: AbstractSet[str] = frozenset()) -> np.ndarray:
    """Perception's overlay drawn again from `labels` (the perceived masks, `Box.mask_label`) and
    `matter` (label k+1 = `scene.unexplained[k]`; None: no region drawn), with the boxes `aside`
    out of the masks and in the matter, after perception's own regions. With nothing aside it is
    perception's overlay, pixel for pixel."""
    out_ids = {b.mask_label: b.id for b in scene.boxes if b.mask_label and b.id in aside}
    kept = labels.copy()
    kept[np.isin(labels, list(out_ids))] = 0
    out = draw_overlay(rgb, kept, box_names(b for b in scene.boxes if b.id not in aside))
    own = matter is not None and matter.shape == labels.shape and bool(scene.unexplained)
    regions = np.array(matter, np.uint16) if own else np.zeros(labels.shape, np.uint16)
    region_names = [u.id for u in scene.unexplained or ()] if own else []
    for label, box_id in sorted(out_ids.items()):
        region_names.append(f"aside-{box_id}")
        regions[(labels == label) & (regions == 0)] = len(region_names)
    return draw_unexplained(out, regions, region_names) if region_names else out


def segmentation_image(rgb: np.ndarray | None, overlay: np.ndarray | None, labels: np.ndarray | None,
                       matter: np.ndarray | None, scene: Scene | None, aside: AbstractSet[str]) -> np.ndarray | None:
    """What the Segmentation image shows: perception's `overlay` while no face of `scene` is set
    aside (or the capture's label images are not at hand: a session stored before they were),
    else `draw_segmentation` with them set aside."""
    if scene is None or rgb is None or labels is None or labels.shape != rgb.shape[:2]:
        return overlay
    if not {b.id for b in scene.boxes if b.mask_label} & set(aside):
        return overlay
    return draw_segmentation(rgb, labels, matter, scene, aside)


def set_aside_entries(plans: Sequence[Plan]) -> list[Mapping[str, Any]]:
    """What the plans set aside (`extra["set_aside"]`; both planners plan on one scene, so they
    repeat each other, which `SetAside.from_entries` skips); a stored entry of another shape is left out."""
    return [e for p in plans for e in (p.extra or {}).get("set_aside") or ()
            if isinstance(e, Mapping) and isinstance(e.get("boxes"), list)]


def set_aside_boxes(plans: Sequence[Plan]) -> frozenset[str]:
    """The ids of the boxes any of `plans` set aside."""
    return frozenset(str(b) for e in set_aside_entries(plans) for b in e["boxes"])


__all__ = ["draw_segmentation", "segmentation_image", "set_aside_boxes", "set_aside_entries"]
