"""Round 11 catalogue rules (box_catalogue): a staircase of offset faces of one colour is cut
into its type faces; a face part merged with the box below across a depth step goes back to
its face's pieces."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.evaluation.bench import mask_iou
from shelfpick.perception.box_catalogue import Catalogue, apply_catalogue
from shelfpick.perception.repairs.measure import RepairContext
from shelfpick.perception.repairs.splits import split_faces
from shelfpick.perception.scene import Scene, Shelf
from synth_frames import COLOURS, box, cast


def _front(cap, k: int) -> np.ndarray:
    """The front-face pixels of box k (cast paints them in the box's own colour)."""
    return (cap.masks == k) & np.all(cap.rgb == np.asarray(COLOURS[k - 1]), axis=-1)


def _staircase(fronts: tuple[float, ...]):
    """Four 50x17 boxes stacked, pushed left and right (as planning shelf 5003), one colour."""
    xs = (0.05, 0.05, -0.12, -0.10)
    scene = Scene(Shelf(), tuple(box(f"b{k}", x, 0.17 * k, 0.50, 0.17, front=f)
                                 for k, (x, f) in enumerate(zip(xs, fronts))))
    cap = cast(scene)
    faces = [_front(cap, k) for k in range(1, 5)]
    rgb = cap.rgb.copy()
    union = np.any(faces, axis=0)
    rgb[union] = (180, 140, 95)
    return cap, rgb, faces, union


def test_a_staircase_of_offset_faces_of_one_colour_is_cut_into_its_type_faces():
    cat = Catalogue()
    cap, rgb, faces, union = _staircase((0.02, 0.035, 0.028, 0.02))   # fronts 0.7-1.5 cm apart
    out, notes = split_faces([union], RepairContext(cap.depth, cap.camera, cat, rgb))
    assert len(out) == 4, notes
    for f in faces:
        assert max(mask_iou(o, f) for o in out) > 0.85, notes
    assert any("staircase" in n for n in notes), notes


def test_a_flat_staircase_without_seams_is_left_whole():
    # one colour, one front plane: nothing says where the boxes meet, so no cut at all
    cap, rgb, faces, union = _staircase((0.02, 0.02, 0.02, 0.02))
    out, notes = split_faces([union], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))
    assert len(out) == 1 and not any("staircase" in n for n in notes), notes


def _stepped(step: float):
    """A 23x25 face on the floor and, on it, a 23x25 face `step` m further back and 4 cm to the
    right, cut by a horizontal tape band: its part below the band merged with the lower face
    (as planning shelf 5035), the band and the part above it left as pieces."""
    scene = Scene(Shelf(), (box("low", -0.10, 0.0, 0.23, 0.25, front=0.02),
                            box("up", -0.06, 0.25, 0.23, 0.25, front=0.02 + step),
                            box("side", 0.25, 0.0, 0.20, 0.20)))
    cap = cast(scene)
    low, up, side = _front(cap, 1), _front(cap, 2), _front(cap, 3)
    rows = np.arange(low.shape[0])[:, None]
    ys = np.nonzero(up)[0]
    lo_band, hi_band = int(np.quantile(ys, 0.35)), int(np.quantile(ys, 0.55))   # image rows: down
    top, band, under = up & (rows < lo_band), up & (rows >= lo_band) & (rows < hi_band), up & (rows >= hi_band)
    return cap, low, up, side, top, band, under


def test_a_face_part_merged_across_a_depth_step_goes_back_to_its_pieces():
    cat = Catalogue()
    cap, low, up, side, top, band, under = _stepped(0.017)
    out, _, notes = apply_catalogue([low | under, top, band, side], cap.depth, cap.camera, cap.rgb, cat)
    assert len(out) == 3, notes
    assert max(mask_iou(m, low) for m in out) > 0.9, notes
    assert max(mask_iou(m, up) for m in out) > 0.9, notes
    assert any("off its rest" in n for n in notes), notes


def test_no_depth_step_no_part_given_by_plane():
    # the same masks on one front plane: no depth says which part is whose, this rule stays out
    cat = Catalogue()
    cap, low, up, side, top, band, under = _stepped(0.0)
    _, _, notes = apply_catalogue([low | under, top, band, side], cap.depth, cap.camera, cap.rgb, cat)
    assert not any("off its rest" in n for n in notes), notes
