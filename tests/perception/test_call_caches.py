"""The speed caches of one `perceive` (the frame's points, make_valid's box corners) belong to the
call that made them: shared inside it, gone after it, never shared between threads."""
from __future__ import annotations

import threading

import numpy as np

from shelfpick.perception import contact
from shelfpick.perception.boxes import make_valid
from shelfpick.perception.geometry import _points, point_map, points_cached
from shelfpick.perception.scene import Box, Camera, Shelf

CAM = Camera(32, 24, 30.0, 30.0, 16.0, 12.0, 0.001, (0.0, -1.0, 0.35), (0.7071067811865476, -0.7071067811865476, 0.0, 0.0))


def _depth(value: float = 1.0) -> np.ndarray:
    return np.full((CAM.height, CAM.width), value, np.float32)


def test_a_frames_points_are_computed_once_inside_a_call_and_equal_the_computed_ones():
    depth = _depth()
    with points_cached():
        first, again = point_map(CAM, depth), point_map(CAM, depth.copy())
        assert first is again and not first.flags.writeable
        other = point_map(CAM, _depth(2.0))             # another frame: computed, not the first's
        assert other is not first and not np.array_equal(other, first)
    np.testing.assert_array_equal(first, _points(CAM, depth))


def test_outside_a_call_nothing_is_remembered():
    depth = _depth()
    with points_cached():
        inside = point_map(CAM, depth)
    outside = point_map(CAM, depth)
    assert outside is not inside and outside.flags.writeable


def test_two_threads_do_not_share_a_call_cache():
    depth, seen = _depth(), {}

    def call(name: str) -> None:
        with points_cached() as cache:
            seen[name] = (cache, point_map(CAM, depth))
    threads = [threading.Thread(target=call, args=(n,)) for n in "ab"]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert seen["a"][0] is not seen["b"][0] and seen["a"][1] is not seen["b"][1]


def test_make_valid_remembers_corners_only_while_it_runs():
    shelf = Shelf()
    boxes = [Box("a", (0.0, 0.15, 0.125), (0.23, 0.31, 0.25)), Box("b", (0.0, 0.15, 0.37), (0.23, 0.31, 0.25))]
    out, _ = make_valid(boxes, shelf)
    assert contact._MEMO.get() is None            # the call's memo is gone with the call
    assert len(out) == 2
    corners = contact.box_corners(boxes[0])
    np.testing.assert_array_equal(corners, np.asarray(boxes[0].corners(), float))
