"""The highest-first baseline, against an order computed by hand."""
from __future__ import annotations

import math

import pytest

from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Box, Scene, Shelf, yaw_quat


def _box(bid, x, z, size, yaw=0.0):
    return Box(bid, size, (x, 0.15, z), yaw_quat(yaw))


# Hand computed tops: b 0.40 (on a), c 0.40 (tall, right of b), a 0.20,
# e 0.20 (same top as a, further right), d 0.10 (turned 90 deg: same top).
SCENE = Scene(Shelf(), (
    _box("a", -0.30, 0.10, (0.2, 0.2, 0.2)),
    _box("b", -0.30, 0.30, (0.2, 0.2, 0.2)),
    _box("c", 0.00, 0.20, (0.2, 0.2, 0.4)),
    _box("d", 0.30, 0.05, (0.3, 0.2, 0.1), yaw=math.pi / 2),
    _box("e", 0.15, 0.10, (0.1, 0.1, 0.2)),
))


def test_clear_order_matches_hand_computed():
    from shelfpick.planning.heuristic import heuristic_order
    assert heuristic_order(SCENE, None) == ("b", "c", "a", "e", "d")


@pytest.mark.parametrize("target, expected", [
    ("b", ("b",)),
    ("c", ("b", "c")),
    ("a", ("b", "c", "a")),
    ("e", ("b", "c", "a", "e")),
    ("d", ("b", "c", "a", "e", "d")),
])
def test_extract_order_is_the_prefix_up_to_the_target(target, expected):
    from shelfpick.planning.heuristic import heuristic_order
    assert heuristic_order(SCENE, target) == expected


def test_millimetre_jitter_does_not_reorder_level_boxes():
    from shelfpick.planning.heuristic import heuristic_order
    jittered = Scene(Shelf(), (_box("r", 0.2, 0.1002, (0.2, 0.2, 0.2)), _box("l", -0.2, 0.1, (0.2, 0.2, 0.2))))
    assert heuristic_order(jittered, None) == ("l", "r")


def test_unknown_target_is_named():
    from shelfpick.planning.heuristic import heuristic_order
    with pytest.raises(FormatError, match="unknown box id 'zz'"):
        heuristic_order(SCENE, "zz")
