"""perception.overlay draws what it drew before it was made faster (the labels present found by a
count, each label's points found inside its bounding box)."""
from __future__ import annotations

import cv2
import numpy as np
import pytest

from shelfpick.perception.overlay import draw_overlay


def _old_draw_overlay(rgb, labels, names=None, alpha=0.45):
    """draw_overlay as it was at 44ffeb1 (a label image tinted with the full image's colours, each
    label's points found on the whole image)."""
    from shelfpick.perception.overlay import palette

    out = rgb.copy()
    ids = [int(k) for k in np.unique(labels) if k > 0]
    if not ids:
        return out
    cols = palette(max(ids) + 1)
    tint = cols[labels]
    sel = labels > 0
    out[sel] = (out[sel] * (1 - alpha) + tint[sel] * alpha).astype(np.uint8)
    for k in ids:
        pts = cv2.findNonZero((labels == k).astype(np.uint8))
        rect = cv2.minAreaRect(pts)
        corners = cv2.boxPoints(rect).astype(np.int32)
        col = tuple(int(c) for c in cols[k])
        cv2.polylines(out, [corners], True, col, 2, cv2.LINE_AA)
        text = (names or {}).get(k, str(k))
        cx, cy = (int(v) for v in rect[0])
        scale = max(0.6, out.shape[1] / 520)
        thick = max(2, round(2 * scale))
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        org = (cx - tw // 2, cy + th // 2)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (0, 0, 0), thick + 3, cv2.LINE_AA)
        cv2.putText(out, text, org, cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), thick, cv2.LINE_AA)
    return out


@pytest.mark.parametrize("dtype", [np.uint16, np.int32, np.int64])
def test_the_overlay_is_the_one_drawn_before(dtype):
    rng = np.random.default_rng(11)
    rgb = rng.integers(0, 256, size=(90, 120, 3), dtype=np.uint8)
    labels = np.zeros((90, 120), dtype)
    labels[5:40, 10:50] = 1
    labels[50:85, 60:110] = 3                  # label 2 absent
    labels[20:30, 70:100] = 7
    labels[60:70, 5:15] = 7                    # one label in two places
    labels[0:3, 0:120] = 4                     # along the image border
    names = {1: "b0", 3: "b1 ?"}
    np.testing.assert_array_equal(draw_overlay(rgb, labels, names), _old_draw_overlay(rgb, labels, names))
    np.testing.assert_array_equal(draw_overlay(rgb, np.zeros_like(labels)), rgb)
