"""faces.faces_cached: inside one perceive a mask measured again (a new array, the same bits, the
same depth) is not measured again, and gets an equal but separate face; nothing else is shared."""
from __future__ import annotations

import numpy as np

from shelfpick.perception import faces
from shelfpick.perception.faces import faces_cached, measure_front
from shelfpick.perception.scene import Camera

CAM = Camera(64, 48, 60.0, 60.0, 32.0, 24.0, 0.001, (0.0, -1.0, 0.35), (0.7071067811865476, -0.7071067811865476, 0.0, 0.0))


def _mask() -> np.ndarray:
    m = np.zeros((48, 64), bool)
    m[10:30, 15:45] = True
    return m


def _counted(monkeypatch) -> list[int]:
    calls = [0]
    inner = faces._measure_front

    def counting(mask, *a):
        calls[0] += mask.shape == (48, 64)                       # the whole frame's mask, not its crop
        return inner(mask, *a)

    monkeypatch.setattr(faces, "_measure_front", counting)
    return calls


def test_a_mask_is_measured_once_per_depth_inside_a_call(monkeypatch):
    depth = np.full((48, 64), 1.0, np.float32)
    calls = _counted(monkeypatch)
    with faces_cached():
        first = measure_front(_mask(), depth, CAM)
        again = measure_front(_mask(), depth, CAM)              # a new array, the same bits
        assert first is not None and again == first and again is not first
        assert calls[0] == 1
        other = _mask()
        other[29, 44] = False                                    # one pixel less
        measure_front(other, depth, CAM)
        measure_front(_mask(), depth.copy(), CAM)                # another depth array
        measure_front(_mask(), depth, CAM, erode_px=2)           # other settings
        assert calls[0] == 4
    assert measure_front(_mask(), depth, CAM) == first           # outside a call: measured, equal
    assert calls[0] == 5


def test_the_memo_gives_what_measuring_gives():
    depth = np.full((48, 64), 1.0, np.float32)
    depth[:, 40:] = 1.05                                         # a step: the face is not flat
    want = [measure_front(m, depth, CAM) for m in (_mask(), _mask()[::-1].copy(), np.zeros((48, 64), bool))]
    with faces_cached():
        got = [measure_front(m, depth, CAM) for m in (_mask(), _mask()[::-1].copy(), np.zeros((48, 64), bool))]
        got_again = [measure_front(m, depth, CAM) for m in (_mask(), _mask()[::-1].copy(), np.zeros((48, 64), bool))]
    assert got == want == got_again and want[2] is None
