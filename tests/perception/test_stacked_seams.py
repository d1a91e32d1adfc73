"""perception/repairs/stacked_seams.py: the seam between two stacked masks moved onto the depth step
between the cartons' fronts (a print band taken for the seam, `labels` 31056). Depth images and
masks are made here in code."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.repairs.stacked_seams import STEP_HALF, depth_seams, stacked_pairs, step_offset

SEAM = 240          # the true seam: the upper carton's last row
NEAR = STEP_HALF    # rows: the step is found at the first row of its largest change


def _depth(lower_front: float = 1.00, upper_front: float = 1.03) -> np.ndarray:
    """A stack of two cartons 200 px wide: the upper one's rows 120..SEAM, the lower one's below,
    each front at its own distance; the background far behind."""
    d = np.full((480, 640), 2.5, np.float32)
    d[120:SEAM + 1, 200:400] = upper_front
    d[SEAM + 1:360, 200:400] = lower_front
    return d


def _masks(seam: int, gap: int = 0) -> list[np.ndarray]:
    """Two masks over the stack, the upper one ending at row `seam`, the lower one starting `gap`
    rows further down (a band left to neither)."""
    up, low = np.zeros((480, 640), bool), np.zeros((480, 640), bool)
    up[120:seam + 1, 200:400] = True
    low[seam + 1 + gap:360, 200:400] = True
    return [up, low]


def _last_row(m: np.ndarray) -> int:
    return int(np.flatnonzero(m.any(axis=1))[-1])


def test_a_seam_off_the_depth_step_moves_onto_it() -> None:
    masks = _masks(SEAM - 12)                          # the segmenter cut 12 rows high (a band's edge)
    assert stacked_pairs(masks) == [(0, 1)]
    out, moves = depth_seams(masks, _depth())
    assert [(u, lo) for u, lo, _ in moves] == [(0, 1)] and abs(moves[0][2] - 12) <= NEAR
    assert abs(_last_row(out[0]) - SEAM) <= NEAR
    assert not (out[0] & out[1]).any() and (out[0] | out[1]).sum() == (masks[0] | masks[1]).sum()


def test_a_seam_below_the_step_moves_up_and_a_band_left_to_neither_is_shared_out() -> None:
    masks = _masks(SEAM + 10, gap=6)
    out, moves = depth_seams(masks, _depth(lower_front=1.05, upper_front=1.00))
    assert len(moves) == 1 and moves[0][2] < 0
    assert abs(_last_row(out[0]) - SEAM) <= NEAR
    assert (out[0] | out[1])[120:360, 200:400].all()   # the band's rows went to the two cartons


def test_a_seam_on_the_step_and_a_seam_between_flush_fronts_stay() -> None:
    assert step_offset(_masks(SEAM), 0, 1, _depth()) is None
    flush = _masks(SEAM - 12)
    out, moves = depth_seams(flush, _depth(1.0, 1.0))
    assert moves == [] and all((a == b).all() for a, b in zip(out, flush))


def test_masks_that_do_not_sit_one_on_the_other_are_no_seam() -> None:
    up, low = _masks(SEAM - 12)
    narrow = np.zeros_like(low)
    narrow[SEAM - 11:360, 200:260] = True              # a third of the width: another carton
    assert stacked_pairs([up, narrow]) == []
    beside = np.zeros_like(low)
    beside[SEAM - 11:360, 420:620] = True
    assert stacked_pairs([up, beside]) == []
