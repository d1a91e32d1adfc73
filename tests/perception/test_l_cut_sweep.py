"""repairs.l_cuts' line sweep picks the lines it picked before it was vectorised (every line's fills
at once, the corner's window medians by a sort)."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.repairs.l_cuts import _median, _Sweep


def _old_best_fill(sw: _Sweep, margin: int, part_fill: float):
    best = None
    for pos in range(margin, sw.nb - margin + 1):
        if pos <= 0 or pos >= sw.nb or sw.empty_side(pos):
            continue
        score = min(sw.fills(pos))
        if score >= part_fill and (best is None or score > best[0]):
            best = (float(score), pos)
    return best


def _old_corner(sw: _Sweep, margin: int, part_fill: float):
    span = np.where(sw.cnt > 0, sw.omax - sw.omin + 1, 0.0)
    jump = None
    for pos in range(max(margin, 1), sw.nb - max(margin, 1) + 1):
        lo, hi = span[max(0, pos - margin):pos], span[pos:pos + margin]
        if not len(lo) or not len(hi) or sw.empty_side(pos):
            continue
        d = abs(float(np.median(lo)) - float(np.median(hi)))
        if max(sw.fills(pos)) >= part_fill and (jump is None or d > jump[0]):
            jump = (d, pos)
    return None if jump is None else jump[1]


def _l_shapes(n: int):
    """Pixel coordinates of L shapes, rectangles and ragged blobs, some turned."""
    rng = np.random.default_rng(2)
    for _ in range(n):
        m = np.zeros((60, 80), bool)
        y, x, h, w = (int(v) for v in rng.integers(1, 30, 4))
        m[y:y + h + 5, x:x + w + 5] = True
        if rng.random() < 0.7:
            m[y:y + int(rng.integers(2, 10)), x:x + w + int(rng.integers(5, 40))] = True    # the L's foot
        m &= rng.random(m.shape) > rng.choice([0.0, 0.05, 0.3])                              # ragged
        ys, xs = np.nonzero(m)
        if len(ys) < 2:
            continue
        deg = float(rng.choice([0.0, 0.0, 7.0, -12.0]))
        c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
        yield (xs * c + ys * s, ys * c - xs * s) if deg else (xs.astype(float), ys.astype(float))


def test_the_sweep_picks_the_same_lines_as_the_loops_it_replaced():
    picked = 0
    for u, v in _l_shapes(120):
        for t, o in ((v, u), (u, v)):
            sw = _Sweep(t, o)
            for margin in (0, 3, 6):
                for part_fill in (0.5, 0.9):
                    assert sw.best_fill(margin, part_fill) == _old_best_fill(sw, margin, part_fill)
                    got = sw.corner(margin, part_fill)
                    assert got == _old_corner(sw, margin, part_fill)
                    picked += got is not None
    assert picked > 200                                   # the cases are not all "no line"


def test_median_is_numpys():
    rng = np.random.default_rng(4)
    for n in range(1, 12):
        for _ in range(50):
            v = rng.integers(0, 9, n).astype(float) * rng.choice([1.0, 0.37])
            assert _median(v) == float(np.median(v))
