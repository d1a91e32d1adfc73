"""perception/repairs/halves.py and pipeline._regroup_halves: two masks that are the left and right
halves of two stacked cartons of one print (a stack cut down a band, issue 31, `labels` look)
re-cut where the print repeats. Frames are painted here in code (not the generators')."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.boxes import planar_depth
from shelfpick.perception.capture import Capture
from shelfpick.perception.pipeline import _regroup_halves, perceive
from shelfpick.perception.scene import Camera, Shelf

CAM = Camera(640, 480, 600.0, 600.0, 320.0, 240.0)     # 1.04 m before the shelf front, looking along +y
BOARD = (200, 165, 115)
STACK = (90, 350, 180, 400)          # rows, columns of two stacked fronts, 130 px (22.5 cm) each
SEAM = 220                           # the row between them
CUT = 224                            # the column down the band's left edge where the halves meet:
#                                      the left half 7.6 cm wide, too narrow for a repeat cut of its own


def _carton(rgb: np.ndarray, y0: int, y1: int, x0: int, x1: int, printed: bool = True) -> None:
    """One carton front, laid out in fractions of the face (u left-right, v top-bottom): a logo,
    text rows and a short band across in its left fifth, then a band down the face (where a
    segmenter cuts), plain board to the right (no print along the rows there)."""
    vs, us = np.mgrid[y0:y1, x0:x1]
    u, v = (us - x0) / (x1 - x0), (vs - y0) / (y1 - y0)
    face = np.zeros(u.shape + (3,), np.uint8)
    face[:] = BOARD
    if printed:
        left = u < 0.2
        face[left & (v > 0.1) & (v < 0.4)] = (30, 120, 130)                            # logo
        face[left & (v > 0.5) & (v < 0.7) & (np.floor(v * 40) % 3 == 0)] = (25, 25, 25)  # text
        face[left & (v > 0.8) & (v < 0.9)] = (200, 190, 40)                            # band across
        face[(u >= 0.2) & (u < 0.35)] = (150, 40, 150)                                 # band down
    rgb[y0:y1, x0:x1] = face


def _frame(printed: bool = True) -> np.ndarray:
    rgb = np.full((480, 640, 3), 80, np.uint8)
    y0, y1, x0, x1 = STACK
    _carton(rgb, y0, SEAM, x0, x1, printed)
    _carton(rgb, SEAM, y1, x0, x1, printed)        # the same carton below, flush: no seam line
    return rgb


def _mask(y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    m = np.zeros((480, 640), bool)
    m[y0:y1, x0:x1] = True
    return m


def _halves() -> list[np.ndarray]:
    y0, y1, x0, x1 = STACK
    return [_mask(y0, y1, x0, CUT), _mask(y0, y1, CUT, x1)]


class _Masks:
    """A segmenter that returns the masks it was given (the halves a real one made)."""

    name = "given"

    def __init__(self, masks: list[np.ndarray]) -> None:
        self.masks = masks

    def segment(self, rgb: np.ndarray, depth: np.ndarray | None) -> list[np.ndarray]:
        return [m.copy() for m in self.masks]


def test_perceive_recuts_the_two_halves_of_a_printed_stack_into_its_two_cartons() -> None:
    """Failed before repairs.halves: two boxes 45 cm high (each half a stack) came out."""
    res = perceive(Capture(_frame(), planar_depth(CAM, 1.04), CAM), segmenter=_Masks(_halves()),
                   catalogue=None)
    assert len(res.scene.boxes) == 2
    assert any("halves of 2 fronts of one print stacked" in n for n in res.adjustments)
    carton_h, carton_w = 130 / 600 * 1.04, 220 / 600 * 1.04
    for b in res.scene.boxes:
        assert abs(b.size[2] - carton_h) <= 0.015 and abs(b.size[0] - carton_w) <= 0.015, b.size
    tops = sorted(b.position[2] + b.size[2] / 2 for b in res.scene.boxes)
    assert tops[1] - tops[0] >= carton_h - 0.015             # one above the other


def test_cartons_in_their_own_masks_a_depth_step_and_plain_fronts_are_left_alone() -> None:
    y0, y1, x0, x1 = STACK
    depth = planar_depth(CAM, 1.04)
    right = _mask(0, 480, CUT, 640)
    stepped = np.where(right, depth + 0.03, depth).astype(depth.dtype)    # right half 3 cm deeper
    cases = {
        "each carton its own mask": (_frame(), depth, [_mask(y0, SEAM, x0, x1), _mask(SEAM, y1, x0, x1)]),
        "halves a depth step apart": (_frame(), stepped, _halves()),
        "halves of plain fronts": (_frame(printed=False), depth, _halves()),
    }
    for name, (rgb, d, masks) in cases.items():
        out, faces, notes = _regroup_halves(masks, None, Capture(rgb, d, CAM), Shelf())
        assert not notes and len(out) == 2, name
        assert all(np.array_equal(a, b) for a, b in zip(out, masks)), name
        assert all(f is not None for f in faces), name


def test_halves_recut_at_the_seam_each_part_a_whole_carton() -> None:
    out, faces, notes = _regroup_halves(_halves(), None, Capture(_frame(), planar_depth(CAM, 1.04), CAM), Shelf())
    assert len(notes) == 1 and len(out) == 2 and all(f is not None for f in faces)
    rows = sorted((int(np.flatnonzero(p.any(1))[0]), int(np.flatnonzero(p.any(1))[-1])) for p in out)
    assert abs(rows[0][1] - (SEAM - 1)) <= 3 and abs(rows[1][0] - SEAM) <= 3
    for p in out:                                            # each part spans the whole width
        cols = np.flatnonzero(p.any(0))
        assert cols[0] <= STACK[2] + 2 and cols[-1] >= STACK[3] - 3


def test_a_strip_of_left_halves_beside_two_right_halves_is_recut_into_the_two_cartons() -> None:
    """`labels` 31028: the left halves of two stacked cartons in one mask, their right halves in two:
    no pair of the three makes a flush block, the three together do."""
    y0, y1, x0, x1 = STACK
    masks = [_mask(y0, y1, x0, CUT), _mask(y0, SEAM, CUT, x1), _mask(SEAM, y1, CUT, x1)]
    out, faces, notes = _regroup_halves(masks, None, Capture(_frame(), planar_depth(CAM, 1.04), CAM), Shelf())
    assert len(notes) == 1 and "halves of 2 fronts of one print stacked" in notes[0]
    assert len(out) == 2 and all(f is not None for f in faces)
    for p in out:                                            # each part a whole carton: the full width
        cols = np.flatnonzero(p.any(0))
        assert cols[0] <= x0 + 2 and cols[-1] >= x1 - 3
    rows = sorted((int(np.flatnonzero(p.any(1))[0]), int(np.flatnonzero(p.any(1))[-1])) for p in out)
    assert abs(rows[0][1] - (SEAM - 1)) <= 3 and abs(rows[1][0] - SEAM) <= 3


def test_a_strip_beside_the_two_cartons_it_already_belongs_to_is_not_recut() -> None:
    """Three masks that are already three fronts (a narrow carton beside two stacked ones, plain
    board: no print to repeat) stay as they are."""
    y0, y1, x0, x1 = STACK
    masks = [_mask(y0, y1, x0, CUT), _mask(y0, SEAM, CUT, x1), _mask(SEAM, y1, CUT, x1)]
    out, _, notes = _regroup_halves(masks, None, Capture(_frame(printed=False), planar_depth(CAM, 1.04), CAM), Shelf())
    assert not notes and all(np.array_equal(a, b) for a, b in zip(out, masks))
