"""perception/repairs/merged.py and boxes.split_merged: masks that are two boxes, cut by geometry
(issue 31): a depth step through a mask, an L outline that used to be dropped as 'not a box front',
thin strands along a neighbour's edge, a top face of the same colour seen from above."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.boxes import boxes_from_masks, planar_depth
from shelfpick.perception.repairs.merged import depth_step_parts, off_plane_trimmed, rect_fill, rectangle_parts, trimmed
from shelfpick.perception.scene import Camera, Shelf

CAM = Camera(640, 480, 600.0, 600.0, 320.0, 240.0)     # 1.04 m before the shelf front, looking along +y
MIN_PX = 150


def _rect(y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    m = np.zeros((480, 640), bool)
    m[y0:y1, x0:x1] = True
    return m


def test_a_depth_step_through_a_mask_cuts_it_into_the_two_fronts() -> None:
    depth = planar_depth(CAM, 1.04).copy()
    depth[:, 320:] += 0.05                              # the right box stands 5 cm further back
    mask = _rect(200, 320, 220, 420)
    parts = depth_step_parts(mask, depth, MIN_PX)
    assert len(parts) == 2
    assert sorted(int(p.sum()) for p in parts) == [120 * 100, 120 * 100]
    assert not (parts[0] & parts[1]).any() and np.array_equal(parts[0] | parts[1], mask)


def test_no_cut_on_one_surface_a_small_step_or_a_line_of_depth_holes() -> None:
    flat = planar_depth(CAM, 1.04).copy()
    mask = _rect(200, 320, 220, 420)
    assert len(depth_step_parts(mask, flat, MIN_PX)) == 1
    small = flat.copy()
    small[:, 320:] += 0.01                              # a label's thickness, not two fronts
    assert len(depth_step_parts(mask, small, MIN_PX)) == 1
    holes = flat.copy()
    holes[:, 318:322] = 0.0                             # no measurement is no step
    assert len(depth_step_parts(mask, holes, MIN_PX)) == 1


def test_an_l_outline_is_cut_at_its_corner_into_two_filled_rectangles() -> None:
    tall, low = _rect(140, 240, 200, 240), _rect(210, 240, 240, 360)
    mask = tall | low
    assert rect_fill(mask) < 0.5
    parts = rectangle_parts(mask, MIN_PX)
    assert len(parts) == 2 and all(rect_fill(p) > 0.9 for p in parts)
    assert rectangle_parts(_rect(100, 200, 100, 300), MIN_PX)[0].sum() == 100 * 200   # a rectangle stays


def test_two_boxes_in_one_badly_filled_mask_are_two_boxes_not_a_hole() -> None:
    """The issue's shelf: two bottom boxes of one colour at one depth became one mask filling a fraction
    of its rectangle and were dropped; the scene went on without either box."""
    depth = planar_depth(CAM, 1.04)
    mask = _rect(80, 240, 200, 240) | _rect(200, 240, 240, 400)
    before = boxes_from_masks([mask], depth, CAM, Shelf())
    assert before[0] == [] and "not a box front" in before[3][0]           # the old behaviour: a hole
    boxes, masks, faces, said = boxes_from_masks([mask], depth, CAM, Shelf(), split_min_px=MIN_PX)
    assert len(boxes) == 2 and any("2 fronts" in s for s in said)
    widths = sorted(round(f.width * 100) for f in faces)
    assert widths == [7, 28]                                               # 40 px and 160 px at 1.04 m


def test_a_thin_strand_along_a_neighbours_edge_is_trimmed_not_the_box_dropped() -> None:
    box = _rect(200, 300, 250, 350)
    strand = _rect(198, 200, 150, 450)                  # 2 px along the edge of the box above
    assert rect_fill(box | strand) < 0.5
    t = trimmed(box | strand)
    assert (t >= box).all() and not t[:, :250].any() and not t[:, 350:].any()   # the box, no strand beside it
    boxes, _, faces, _ = boxes_from_masks([box | strand], planar_depth(CAM, 1.04), CAM, Shelf(), split_min_px=MIN_PX)
    assert len(boxes) == 1 and round(faces[0].width * 100) == 17


def test_pixels_off_the_face_plane_are_trimmed() -> None:
    depth = planar_depth(CAM, 1.04).copy()
    mask = _rect(200, 320, 220, 420)
    depth[200:215, 220:420] += 0.05                     # a top face seen from above: behind the front
    kept = off_plane_trimmed(mask, (0.0, 0.0, 0.8), np.array([0.0, 1.0, 0.0]), depth, CAM)
    assert kept.sum() == 105 * 200 and not kept[200:215].any()
    assert off_plane_trimmed(mask, (0.0, 0.0, 0.8), np.array([0.0, 1.0, 0.0]), planar_depth(CAM, 1.04), CAM) is mask


def test_a_top_edge_hidden_behind_a_box_in_front_is_seen() -> None:
    from shelfpick.perception.repairs.merged import top_edge_hidden

    depth = planar_depth(CAM, 1.04).copy()
    mask = _rect(200, 320, 220, 420)
    assert not top_edge_hidden(mask, depth)
    depth[150:200, 200:440] = 0.97                      # a box standing 7 cm proud just above
    assert top_edge_hidden(mask, depth)


def _box(i: str, z0: float, h: float, hidden: bool = False):
    from shelfpick.perception.scene import Box

    extra = {"perceived": {"top_hidden": True}} if hidden else {"perceived": {}}
    return Box(i, (0.2, 0.2, h), (0.0, 0.1, z0 + h / 2), (1.0, 0.0, 0.0, 0.0), None, False, 1, extra)


def test_a_box_over_a_support_whose_top_was_hidden_grows_the_support_not_drops() -> None:
    from shelfpick.perception.boxes import make_valid

    shelf = Shelf()
    boxes, notes = make_valid([_box("b0", 0.0, 0.15, hidden=True), _box("b1", 0.2, 0.2)], shelf)
    assert boxes[1].position[2] == pytest.approx(0.3) and boxes[0].size[2] == pytest.approx(0.2)
    assert boxes[0].position[2] == pytest.approx(0.1)
    assert any("top edge hidden" in n for n in notes)
    boxes, _ = make_valid([_box("b0", 0.0, 0.15), _box("b1", 0.2, 0.2)], shelf)         # seen whole: dropped
    assert boxes[1].position[2] == pytest.approx(0.25) and boxes[0].size[2] == pytest.approx(0.15)
