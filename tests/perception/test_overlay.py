"""The overlay's names of unexplained regions: inside their region, and never over one another."""
from __future__ import annotations

import cv2
import numpy as np

from shelfpick.perception.overlay import draw_unexplained, name_spot


def _centre(org: tuple[int, int], size: tuple[int, int]) -> tuple[int, int]:
    return org[0] + size[0] // 2, org[1] - size[1] // 2


def test_an_l_shaped_region_is_named_inside_itself_not_at_its_box_centre():
    m = np.zeros((200, 200), np.uint8)
    m[10:190, 10:50] = 1                     # an L: its bounding box's centre (100, 100) is outside it
    m[150:190, 10:190] = 1
    size = (30, 12)
    x, y = _centre(name_spot(m, size, []), size)
    assert m[y, x] == 1 and m[100, 100] == 0


def test_names_of_regions_side_by_side_do_not_overlap_and_stay_in_the_image():
    labels = np.zeros((120, 160), np.uint16)
    labels[40:80, 60:70] = 1                 # a thin strip beside a block: both centred near x=70
    labels[40:80, 72:110] = 2
    labels[0:6, 150:160] = 3                 # in a corner: its name is kept inside the image
    written: list[tuple[int, int, int, int]] = []
    spots = [name_spot((labels == k).astype(np.uint8), (44, 12), written) for k in (1, 2, 3)]
    a, b = written[0], written[1]
    assert not (a[0] < b[2] and b[0] < a[2] and a[1] < b[3] and b[1] < a[3])
    assert all(0 <= x and x + 44 <= 160 and 12 <= y < 120 for x, y in spots)
    rgb = np.full((120, 160, 3), 180, np.uint8)
    out = draw_unexplained(rgb, labels, ["u0", "aside-b6", "u1"])
    white = np.all(out == 255, axis=-1) & ~(cv2.dilate((labels > 0).astype(np.uint8), np.ones((5, 5))) == 0)
    assert white.any()                       # the names were written over their regions
