"""Faces cut by the image border: kept (at least as big as seen), completed to a type face where
the catalogue explains them, and always warned about (the scene may be incomplete there)."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.box_catalogue import Catalogue
from shelfpick.perception.faces import measure_front
from shelfpick.perception.masks import border_sides
from shelfpick.perception.pipeline import perceive
from shelfpick.perception.repairs.border_cut import complete_cut_face, cut_directions
from shelfpick.perception.scene import Scene, Shelf
from shelfpick.perception.segment_depth import DepthEdgeSegmenter
from synth_frames import box, cast

# SMALL_CAMERA sees the front plane (y = 0.02) up to z ~ 0.758 m


def _stack(top_bottom: float) -> Scene:
    """A 40 cm wide box on the floor, a 23x25 cm carton on it, and a 50x17 cm long box on the
    carton whose bottom is at `top_bottom` (only its lowest part is in view)."""
    return Scene(Shelf(), (box("c", 0.0, 0.0, 0.40, top_bottom - 0.25, d=0.30),
                           box("a", 0.0, top_bottom - 0.25, 0.23, 0.25, d=0.31, front=0.03),
                           box("b", 0.05, top_bottom, 0.50, 0.17, d=0.17)))


def _top(res):
    return max(res.scene.boxes, key=lambda b: b.position[2])


@pytest.mark.parametrize("bottom", [0.70, 0.74])
def test_face_cut_by_top_border_is_kept_completed_and_warned(bottom):
    scene = _stack(bottom)
    cap = cast(scene, noise=0.001)
    assert cap.masks[0].any()                       # the long box does reach the top border
    res = perceive(cap, DepthEdgeSegmenter(), scene.shelf)
    assert len(res.scene.boxes) == 3, res.adjustments
    top = _top(res)
    m = res.masks == top.mask_label
    assert "top" in border_sides(m)
    vals, counts = np.unique(cap.masks[m], return_counts=True)
    assert cap.labels[int(vals[np.argmax(counts)])] == "b"
    # completed to the 50x17 cm type face, grown upwards from its seen bottom edge
    assert abs(top.size[0] - 0.50) < 0.02 and abs(top.size[2] - 0.17) < 0.015, top.size
    assert abs(top.position[2] - top.size[2] / 2 - bottom) < 0.02
    assert any(top.id in w and "top image border" in w for w in res.warnings), res.warnings
    assert any(top.id in a and "type face" in a for a in res.adjustments), res.adjustments


def test_without_catalogue_a_cut_face_is_kept_at_least_as_seen():
    scene = _stack(0.70)
    cap = cast(scene, noise=0.001)
    res = perceive(cap, DepthEdgeSegmenter(), scene.shelf, catalogue=None)
    assert len(res.scene.boxes) == 3
    top = _top(res)
    assert 0.04 < top.size[2] < 0.08             # ~5.8 cm in view, nothing invented
    assert any(top.id in w and "top image border" in w for w in res.warnings)


def test_a_cut_face_is_completed_only_in_a_capture_of_the_catalogue_types():
    # a catalogue of other stock that holds the long box's 50x17 face but none of the faces below
    # it: the capture is not of these types (as the neura pallet is not of the default ones), so
    # the cut face is kept as seen, not completed to 50x17
    scene = _stack(0.70)
    cap = cast(scene, noise=0.001)
    other = Catalogue(types=((0.34, 0.25, 0.20), (0.50, 0.17, 0.17)))
    res = perceive(cap, DepthEdgeSegmenter(), scene.shelf, catalogue=other)
    assert len(res.scene.boxes) == 3
    top = _top(res)
    assert 0.04 < top.size[2] < 0.08, top.size
    assert not any("type face" in a for a in res.adjustments), res.adjustments
    assert any(top.id in w and "top image border" in w for w in res.warnings)


def test_no_border_warning_when_everything_is_in_view():
    scene = Scene(Shelf(), (box("c", 0.0, 0.0, 0.40, 0.30, d=0.30),))
    res = perceive(cast(scene, noise=0.001), DepthEdgeSegmenter(), scene.shelf)
    assert len(res.scene.boxes) == 1
    assert not any("image border" in w for w in res.warnings)


def test_cut_direction_and_completion_on_a_measured_face():
    scene = _stack(0.70)
    cap = cast(scene, noise=0.0)
    m = cap.masks == 3
    f = measure_front(m, cap.depth, cap.camera)
    assert cut_directions(f, m, cap.camera) == {"+z"}
    g, cut, how = complete_cut_face(f, m, cap.camera, Catalogue())
    assert how == "type" and abs(g.height - 0.17) < 0.005
    # grown away from the border: the bottom edge stays where it was seen
    assert abs((g.center[2] - g.height / 2) - (f.center[2] - f.height / 2)) < 1e-6
    # a catalogue without a type of that width: kept as seen
    g2, _, how2 = complete_cut_face(f, m, cap.camera, Catalogue(types=((0.3, 0.3, 0.3),)))
    assert how2 is None and g2 == f


def test_error_cut_counts_a_cut_side_only_where_too_long():
    cat = Catalogue()
    assert cat.error_cut(0.50, 0.05, {"z"}) < 1e-9          # the bottom of a 50x17 face
    assert cat.error(0.50, 0.05) > 0.1
    assert cat.error_cut(0.40, 0.05, {"z"}) > cat.tol        # no type is 40 cm wide


def test_pieces_cut_by_the_same_border_join_but_a_border_strip_never_joins_a_face_below():
    from shelfpick.perception.repairs.joins import join_pieces
    from shelfpick.perception.repairs.measure import RepairContext

    scene = _stack(0.70)
    cap = cast(scene, noise=0.0)
    top, carton = cap.masks == 3, cap.masks == 2
    xs = np.nonzero(top)[1]
    # cut down a tape line into 12 and 37 cm pieces (no type is that wide: pieces, not faces;
    # a half of 25 cm could be a cut 25 cm face and is rightly left alone)
    cut = int(xs.min() + 0.24 * (xs.max() - xs.min()))
    cols = np.arange(top.shape[1])[None, :]
    left, right = top & (cols < cut - 3), top & (cols > cut + 3)
    out, notes = join_pieces([left, right, carton], RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 2 and notes
    assert any((o & left).any() and (o & right).any() for o in out)
    assert any((o == carton).all() for o in out)             # the carton is left alone
    # a strip along the top border beside a carton that does not reach the border: kept apart
    strip = top & (np.arange(top.shape[0])[:, None] < 6)
    out, _ = join_pieces([strip, carton], RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 2
