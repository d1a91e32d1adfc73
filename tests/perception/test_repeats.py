"""perception/repairs/repeats.py and pipeline._repeat_cuts: cartons of one printed design, stacked
or side by side at one depth in one mask, cut where the print repeats (issue 31, `labels` look).
Frames are painted here in code (not the generators')."""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.boxes import planar_depth
from shelfpick.perception.capture import Capture
from shelfpick.perception.faces import measure_front
from shelfpick.perception.pipeline import perceive
from shelfpick.perception.repairs.repeats import repeat_parts
from shelfpick.perception.scene import Camera, Shelf

CAM = Camera(640, 480, 600.0, 600.0, 320.0, 240.0)     # 1.04 m before the shelf front, looking along +y
BOARD = (205, 170, 120)


def _paint(rgb: np.ndarray, y0: int, y1: int, x0: int, x1: int, design: str = "print") -> None:
    """One carton front: the design laid out in fractions of the face (u left-right, v bottom-top)."""
    vs, us = np.mgrid[y0:y1, x0:x1]
    u, v = (us - x0) / (x1 - x0), 1 - (vs - y0) / (y1 - y0)
    face = np.zeros(u.shape + (3,), np.uint8)
    face[:] = BOARD
    if design == "print":
        face[(v > 0.12) & (v < 0.3)] = (30, 60, 160)                               # a band
        face[(u > 0.1) & (u < 0.35) & (v > 0.55) & (v < 0.85)] = (190, 30, 40)      # a logo
        face[(u > 0.45) & (u < 0.9) & (v > 0.5) & (v < 0.9) & (np.floor(v * 30) % 3 == 0)] = (20, 20, 20)
    elif design == "down":
        face[(u > 0.4) & (u < 0.6)] = (30, 60, 160)                                 # a band down the face
    rgb[y0:y1, x0:x1] = face


def _lab(rgb: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb.astype(np.float32) / 255.0, cv2.COLOR_RGB2LAB)


def _mask(y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    m = np.zeros((480, 640), bool)
    m[y0:y1, x0:x1] = True
    return m


def test_two_stacked_cartons_of_one_print_in_one_mask_are_cut_at_their_seam() -> None:
    rgb = np.full((480, 640, 3), 90, np.uint8)
    _paint(rgb, 100, 230, 200, 400)
    _paint(rgb, 230, 360, 200, 400)                    # the same carton below, flush: no seam line
    parts, axis, score = repeat_parts(_mask(100, 360, 200, 400), _lab(rgb))
    assert axis == 0 and len(parts) == 2 and score > 0.9
    rows = sorted((int(np.flatnonzero(p.any(1))[0]), int(np.flatnonzero(p.any(1))[-1])) for p in parts)
    assert abs(rows[0][1] - 229) <= 3 and abs(rows[1][0] - 230) <= 3


def test_two_cartons_side_by_side_of_one_print_are_cut_at_their_seam() -> None:
    rgb = np.full((480, 640, 3), 90, np.uint8)
    _paint(rgb, 150, 300, 100, 280)
    _paint(rgb, 150, 300, 280, 460)
    parts, axis, _ = repeat_parts(_mask(150, 300, 100, 460), _lab(rgb))
    assert axis == 1 and len(parts) == 2
    cols = sorted(int(np.flatnonzero(p.any(0))[0]) for p in parts)
    assert abs(cols[1] - 280) <= 3


def test_one_printed_carton_a_plain_one_and_a_band_along_the_cut_axis_are_never_cut() -> None:
    for design, box in (("print", (100, 300, 200, 400)), ("print", (100, 360, 200, 330)),
                        ("plain", (100, 360, 200, 400))):
        rgb = np.full((480, 640, 3), 90, np.uint8)
        _paint(rgb, *box, design=design)
        assert len(repeat_parts(_mask(*box), _lab(rgb))[0]) == 1, (design, box)
    rgb = np.full((480, 640, 3), 90, np.uint8)          # two stacked, a band running down both:
    _paint(rgb, 100, 230, 200, 400, "down")             # nothing along the rows repeats
    _paint(rgb, 230, 360, 200, 400, "down")
    assert len(repeat_parts(_mask(100, 360, 200, 400), _lab(rgb))[0]) == 1


def test_perceive_cuts_a_merged_mask_of_two_printed_fronts_into_two_boxes() -> None:
    """The pipeline step: one mask over two stacked fronts of one print at one depth (the learned
    segmenter's merge on the `labels` tuning look) leaves as two fronts, each measured as a box."""
    from shelfpick.perception.pipeline import _repeat_cuts

    rgb = np.full((480, 640, 3), 90, np.uint8)
    _paint(rgb, 100, 230, 200, 400)
    _paint(rgb, 230, 360, 200, 400)
    depth = planar_depth(CAM, 1.04)
    cap = Capture(rgb, depth, CAM)
    masks, notes = _repeat_cuts([_mask(100, 360, 200, 400)], cap, Shelf())
    faces = [measure_front(m, depth, CAM) for m in masks]
    assert len(masks) == 2 and all(f is not None for f in faces)
    assert notes and "2 fronts of one print stacked" in notes[0]
    heights = sorted(round(f.height, 2) for f in faces)
    assert abs(heights[0] - heights[1]) <= 0.015 and abs(sum(heights) - 260 / 600 * 1.04) <= 0.02
    plain = np.full((480, 640, 3), 90, np.uint8)
    _paint(plain, 100, 360, 200, 400, "plain")          # one plain front of the same size stays one
    assert len(_repeat_cuts([_mask(100, 360, 200, 400)], Capture(plain, depth, CAM), Shelf())[0]) == 1


class _OneMask:
    """A segmenter that merged two cartons: it returns one mask over both."""

    name = "one-mask"

    def __init__(self, mask: np.ndarray) -> None:
        self.mask = mask

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None) -> list[np.ndarray]:
        return [self.mask]


def test_perceive_makes_two_boxes_of_two_stacked_printed_cartons_a_segmenter_merged() -> None:
    rgb = np.full((480, 640, 3), 90, np.uint8)
    _paint(rgb, 100, 230, 200, 400)
    _paint(rgb, 230, 360, 200, 400)
    seg = _OneMask(_mask(100, 360, 200, 400))
    res = perceive(Capture(rgb, planar_depth(CAM, 1.04), CAM), segmenter=seg, catalogue=None)
    assert len(res.scene.boxes) == 2
    assert any("2 fronts of one print stacked" in n for n in res.adjustments)
    assert all(abs(b.size[2] - 130 / 600 * 1.04) <= 0.015 for b in res.scene.boxes)


def _paint_taped(rgb: np.ndarray, y0: int, y1: int, x0: int, x1: int) -> None:
    """A carton front of the `labels` kind: a tape down one side, a label and a tag: little that
    runs across the face, so where the tape falls in a row weighs most."""
    vs, us = np.mgrid[y0:y1, x0:x1]
    u, v = (us - x0) / (x1 - x0), 1 - (vs - y0) / (y1 - y0)
    face = np.zeros(u.shape + (3,), np.uint8)
    face[:] = BOARD
    face[(u > 0.1) & (u < 0.25)] = (40, 160, 120)
    face[(u > 0.35) & (u < 0.7) & (v > 0.6) & (v < 0.85)] = (235, 235, 235)
    face[(u > 0.45) & (u < 0.55) & (v > 0.45) & (v < 0.6)] = (170, 40, 70)
    rgb[y0:y1, x0:x1] = face


def test_a_stack_of_cartons_not_aligned_in_the_image_is_cut_carton_by_carton() -> None:
    """Stacked cartons of one print pushed a little left or right of each other (labels 31028's
    column): each row's strips follow the row's own extent, so the print repeats; on the mask's
    bounding box the tape fell in other strips in every carton and the stack was not cut, or cut
    in two where it is three."""
    for offsets in ((0, 12, -8, 6), (0, -10, 8)):
        rgb = np.full((480, 640, 3), 90, np.uint8)
        m = np.zeros((480, 640), bool)
        for k, o in enumerate(offsets):
            _paint_taped(rgb, 60 + 70 * k, 130 + 70 * k, 250 + o, 330 + o)
            m[60 + 70 * k:130 + 70 * k, 250 + o:330 + o] = True
        parts, axis, _ = repeat_parts(m, _lab(rgb))
        assert axis == 0 and len(parts) == len(offsets), offsets
        tops = sorted(int(np.flatnonzero(p.any(1))[0]) for p in parts)
        assert all(abs(t - (60 + 70 * k)) <= 3 for k, t in enumerate(tops)), (offsets, tops)


def test_a_printed_stack_merged_with_a_deeper_front_is_parted_at_the_step_then_cut() -> None:
    """One mask over two stacked cartons of one print and, beside them, one tall carton 8 cm deeper
    printed once: the two depths together repeat in neither direction; parted at the depth step,
    the stack repeats (`labels` 31028: four cubes and the wide cartons beside them in one mask)."""
    from shelfpick.perception.pipeline import _repeat_cuts

    rgb = np.full((480, 640, 3), 90, np.uint8)
    _paint(rgb, 100, 230, 200, 330)
    _paint(rgb, 230, 360, 200, 330)
    _paint(rgb, 100, 360, 330, 460)
    depth = planar_depth(CAM, 1.04)
    depth[100:360, 330:460] = 1.12
    merged = _mask(100, 360, 200, 460)
    assert len(repeat_parts(merged, _lab(rgb))[0]) == 1        # the whole does not repeat
    masks, notes = _repeat_cuts([merged], Capture(rgb, depth, CAM), Shelf())
    assert len(masks) == 3, notes
    assert notes and "parted at a depth step into 2 fronts" in notes[0] and "2 fronts of one print stacked" in notes[0]
    faces = sorted((f.height for f in (measure_front(m, depth, CAM) for m in masks) if f is not None))
    assert len(faces) == 3 and abs(faces[0] - 130 / 600 * 1.04) <= 0.015 and abs(faces[1] - faces[0]) <= 0.015
