"""Known box types: pieces of one face are joined, a mask of two flush boxes is split at its seam."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.box_catalogue import REFERENCE_TYPES, Catalogue, apply_catalogue
from shelfpick.perception.repairs.enclosed import absorb_enclosed
from shelfpick.perception.repairs.joins import join_pieces
from shelfpick.perception.repairs.l_cuts import cut_l_shapes
from shelfpick.perception.repairs.measure import RepairContext
from shelfpick.perception.repairs.splits import split_faces
from shelfpick.perception.evaluation.bench import mask_iou
from shelfpick.perception.scene import Scene, Shelf
from synth_frames import COLOURS, box, cast


def _front(cap, k: int) -> np.ndarray:
    """The front-face pixels of box k (cast paints them in the box's own colour)."""
    return (cap.masks == k) & np.all(cap.rgb == np.asarray(COLOURS[k - 1]), axis=-1)


def _stack(w: float, h: float):
    """Two flush boxes of one size stacked, and beside them a box of another size."""
    scene = Scene(Shelf(), (box("low", -0.10, 0.0, w, h), box("high", -0.10, h, w, h),
                            box("side", 0.25, 0.0, 0.23, 0.25)))
    cap = cast(scene)
    low, high, side = _front(cap, 1), _front(cap, 2), _front(cap, 3)
    rgb = cap.rgb.copy()
    rgb[low | high] = (180, 140, 95)      # one colour: no colour edge between the two ...
    return cap, rgb, low, high, side


def test_catalogue_faces_and_errors():
    cat = Catalogue()
    assert cat.types == REFERENCE_TYPES
    assert (0.23, 0.25) in cat.faces and (0.5, 0.17) in cat.faces and (0.17, 0.5) in cat.faces
    assert cat.matches(0.205, 0.19) and not cat.matches(0.20, 0.40)
    assert cat.fits(0.30, 0.10) and not cat.fits(0.60, 0.10)
    assert abs(cat.error(0.21, 0.33) - 0.02) < 1e-9
    other = Catalogue(types=((0.34, 0.25, 0.20),))
    assert other.matches(0.34, 0.25) and not other.matches(0.20, 0.20)


def test_two_flush_boxes_of_one_colour_are_split_at_their_seam():
    cap, rgb, low, high, side = _stack(0.20, 0.20)
    seam = np.zeros_like(low)
    rows = np.flatnonzero(high.any(axis=1))
    seam[rows[-1]:rows[-1] + 2] = True    # ... but a faint 2 px seam line where they meet
    rgb[seam & (low | high)] = (150, 115, 80)
    out, notes = split_faces([low | high, side], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))
    assert len(out) == 3, notes
    assert max(mask_iou(m, low) for m in out) > 0.9
    assert max(mask_iou(m, high) for m in out) > 0.9
    assert any("split" in n for n in notes)


def test_no_seam_no_split_and_other_sizes_are_left_alone():
    cap, rgb, low, high, side = _stack(0.20, 0.20)
    # one colour, flush, no line: nothing says where two boxes would meet
    assert len(split_faces([low | high], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))[0]) == 1
    # boxes of a size the catalogue does not hold are never cut up (real data, other stock)
    cap, rgb, low, high, side = _stack(0.34, 0.15)
    rows = np.flatnonzero(high.any(axis=1))
    rgb[rows[-1]:rows[-1] + 2][(low | high)[rows[-1]:rows[-1] + 2]] = (150, 115, 80)
    assert len(split_faces([low | high], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))[0]) == 1


def test_a_face_cut_by_a_label_is_joined_back():
    scene = Scene(Shelf(), (box("a", -0.15, 0.0, 0.23, 0.25), box("b", 0.15, 0.0, 0.20, 0.20)))
    cap = cast(scene)
    a, b = _front(cap, 1), _front(cap, 2)
    rows = np.flatnonzero(a.any(axis=1))
    cut = rows[0] + (rows[-1] - rows[0]) // 3
    label = np.zeros_like(a)
    label[cut:cut + 6] = True             # a label across the face, claimed by no mask
    top, bottom = a & ~label & (np.arange(a.shape[0])[:, None] < cut), a & ~label & \
        (np.arange(a.shape[0])[:, None] >= cut + 6)
    out, notes = join_pieces([top, bottom, b], RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 2, notes
    assert max(mask_iou(m, a) for m in out) > 0.95      # the label's pixels are given back too
    assert max(mask_iou(m, b) for m in out) > 0.99
    # the same pieces with a catalogue of other (smaller) boxes stay apart
    other = RepairContext(cap.depth, cap.camera, Catalogue(types=((0.12, 0.12, 0.12),)))
    assert len(join_pieces([top, bottom, b], other)[0]) == 3


def test_apply_catalogue_leaves_captures_of_other_boxes_alone():
    cap, rgb, low, high, side = _stack(0.20, 0.20)
    rows = np.flatnonzero(high.any(axis=1))
    rgb[rows[-1]:rows[-1] + 2][(low | high)[rows[-1]:rows[-1] + 2]] = (150, 115, 80)
    masks, faces, _ = apply_catalogue([low | high, side], cap.depth, cap.camera, rgb, Catalogue())
    assert len(masks) == 3 and all(f is not None for f in faces)
    # with a catalogue none of these faces belongs to, nothing is changed
    other = Catalogue(types=((0.34, 0.25, 0.45),))
    masks, faces, _ = apply_catalogue([low | high, side], cap.depth, cap.camera, rgb, other)
    assert len(masks) == 2


def test_a_stack_of_three_flush_boxes_of_one_colour_is_cut_one_seam_at_a_time():
    scene = Scene(Shelf(), (box("low", -0.10, 0.0, 0.23, 0.25), box("mid", -0.10, 0.25, 0.20, 0.20),
                            box("high", -0.10, 0.45, 0.23, 0.25), box("side", 0.25, 0.0, 0.20, 0.20)))
    cap = cast(scene)
    low, mid, high, side = (_front(cap, k) for k in (1, 2, 3, 4))
    rgb = cap.rgb.copy()
    rgb[low | mid | high] = (180, 140, 95)
    for upper in (mid, high):               # a faint seam line under the two upper boxes
        rows = np.flatnonzero(upper.any(axis=1))
        band = np.zeros_like(upper)
        band[rows[-1]:rows[-1] + 2] = True
        rgb[band & (low | mid | high)] = (150, 115, 80)
    out, notes = split_faces([low | mid | high, side], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))
    assert len(out) == 4, notes
    for m in (low, mid, high, side):
        assert max(mask_iou(o, m) for o in out) > 0.85, notes
    # without the seams nothing is cut
    plain = cap.rgb.copy()
    plain[low | mid | high] = (180, 140, 95)
    assert len(split_faces([low | mid | high], RepairContext(cap.depth, cap.camera, Catalogue(), plain))[0]) == 1


def _long_on_long():
    """A long box on the floor and another on it, shifted right, rendered: the capture, both
    front-face masks, the pixel grids, the lower box's tape column and the upper box's middle row."""
    scene = Scene(Shelf(), (box("low", 0.0, 0.0, 0.50, 0.17), box("up", 0.20, 0.17, 0.50, 0.17)))
    cap = cast(scene)
    low, up = _front(cap, 1), _front(cap, 2)
    cols = np.arange(low.shape[1])[None, :]
    rows = np.arange(low.shape[0])[:, None]
    lx = np.nonzero(low)[1]
    tape = int(np.median(lx) + 0.2 * np.ptp(lx))
    mid = int(np.median(np.nonzero(up)[0]))
    return cap, low, up, rows, cols, tape, mid


@pytest.mark.parametrize("ragged", [False, True])
def test_l_shaped_mask_is_cut_and_only_rejoined_into_a_type_face(ragged):
    # the segmenter cut the lower box at its tape (x = 0.10 m) and the upper one along its
    # middle, then merged the lower one's right end with the upper one's lower strip: an L.
    # `ragged`: the strip also took a label's lower half with it, so its edge to the rest of its
    # face is ragged and no straight cut leaves two parts that both fill their rectangles; the
    # cut at the L's corner (where the width jumps) must still join the strip back
    cap, low, up, rows, cols, tape, mid = _long_on_long()
    low_left, low_right = low & (cols < tape), low & (cols >= tape)
    up_bottom = up & (rows >= mid)
    if ragged:
        uy, ux = np.nonzero(up)
        up_bottom |= up & (rows >= mid - 0.4 * np.ptp(uy)) & (cols >= ux.min() + 0.25 * np.ptp(ux)) \
            & (cols < ux.min() + 0.75 * np.ptp(ux))
    up_top = up & ~up_bottom
    ell = low_right | up_bottom
    out, notes = cut_l_shapes([low_left, ell, up_top], RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 3 and any("L-shaped" in n for n in notes), notes
    if not ragged:  # one part joined its own box into a type face, the other is a rectangle of its own box
        assert max(mask_iou(o, low) for o in out) > 0.95 or max(mask_iou(o, up) for o in out) > 0.95
    assert all(max(mask_iou(o & t, o) for t in (low, up)) > 0.98 for o in out)
    # the second join pass (as in apply_catalogue) gives both boxes back whole
    out, _ = join_pieces(out, RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 2
    assert max(mask_iou(o, low) for o in out) > 0.95 and max(mask_iou(o, up) for o in out) > 0.95
    # nothing to join it with into a type face: the L stays as it is
    assert len(cut_l_shapes([ell, up_top], RepairContext(cap.depth, cap.camera, Catalogue()))[0]) == 2


def test_a_depth_step_beats_a_label_edge_as_the_seam():
    # a 17x17 end below a 17x50 face 1.5 cm nearer, one colour, merged into one mask: the mask
    # splits into 17x17 + 17x50 at the depth step, or (wrongly) into 17x50 + 17x17 at the lower
    # edge of a white label on the upper box, 17 cm below the top
    scene = Scene(Shelf(), (box("low", 0.0, 0.0, 0.17, 0.17, d=0.17, front=0.035),
                            box("up", 0.0, 0.17, 0.17, 0.50, d=0.17, front=0.02),
                            box("side", 0.30, 0.0, 0.23, 0.25)))
    cap = cast(scene)
    low, up, side = _front(cap, 1), _front(cap, 2), _front(cap, 3)
    rgb = cap.rgb.copy()
    rgb[low | up] = (180, 140, 95)
    rows = np.flatnonzero(up.any(axis=1))
    cols = np.flatnonzero(up.any(axis=0))
    label_bottom = rows[0] + int(round(0.17 / 0.50 * len(rows)))      # 0.50 m above the floor
    band = np.zeros_like(up)
    band[label_bottom - 8:label_bottom, cols[0] + 3:cols[-1] - 8] = True
    rgb[band & up] = (235, 235, 230)
    out, notes = split_faces([low | up, side], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))
    assert len(out) == 3, notes
    assert max(mask_iou(m, low) for m in out) > 0.9 and max(mask_iou(m, up) for m in out) > 0.9, notes
    assert any("depth step" in n for n in notes)


def test_a_face_given_in_part_to_the_box_below_is_cut_back_and_rejoined():
    # a 20x20 cube on a 23x31 face; the segmenter gave the cube's left 65% to the box below
    # (one mask, 23x51: no type face, filling its rectangle > 0.8: no L-shape) and kept its
    # right part as a piece
    scene = Scene(Shelf(), (box("low", -0.10, 0.0, 0.23, 0.31), box("cube", -0.10, 0.31, 0.20, 0.20),
                            box("side", 0.25, 0.0, 0.23, 0.25)))
    cap = cast(scene)
    low, cube, side = _front(cap, 1), _front(cap, 2), _front(cap, 3)
    cols = np.arange(low.shape[1])[None, :]
    xs = np.nonzero(cube)[1]
    cut = int(xs.min() + 0.65 * np.ptp(xs))
    merged, piece = low | (cube & (cols < cut)), cube & (cols >= cut)
    out, _, notes = apply_catalogue([merged, piece, side], cap.depth, cap.camera, cap.rgb, Catalogue())
    assert len(out) == 3, notes
    assert max(mask_iou(m, low) for m in out) > 0.9 and max(mask_iou(m, cube) for m in out) > 0.9, notes
    # with no piece beside it to take the cut-off part, the mask is not cut (a label at a face's
    # end would otherwise be cut off a face measured too long)
    out, _, _ = apply_catalogue([merged, side], cap.depth, cap.camera, cap.rgb, Catalogue())
    assert len(out) == 2


def test_a_face_cut_into_arms_by_a_wide_tape_cross_is_joined_as_a_group():
    # a 50x17 face: the segmenter kept the cross with one quarter (48x16: just no type face) and
    # three quarters as pieces; no pair fills its rectangle, the group does
    scene = Scene(Shelf(), (box("long", 0.0, 0.0, 0.50, 0.17), box("side", 0.36, 0.0, 0.20, 0.20)))
    cap = cast(scene)
    face, side = _front(cap, 1), _front(cap, 2)
    ys, xs = np.nonzero(face)
    rows, cols = np.arange(face.shape[0])[:, None], np.arange(face.shape[1])[None, :]
    cx, cy = int(np.median(xs)), int(np.median(ys))
    hw, hh = int(0.06 * np.ptp(xs)), int(0.15 * np.ptp(ys))
    cross = face & ((np.abs(cols - cx) <= hw) | (np.abs(rows - cy) <= hh))
    quarters = [face & ~cross & (rows < cy) & (cols < cx), face & ~cross & (rows < cy) & (cols > cx),
                face & ~cross & (rows > cy) & (cols < cx), face & ~cross & (rows > cy) & (cols > cx)]
    masks = [cross | quarters[3]] + quarters[:3] + [side]
    out, notes = join_pieces(masks, RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 2, notes
    assert max(mask_iou(m, face) for m in out) > 0.95 and max(mask_iou(m, side) for m in out) > 0.95
    # one quarter taken by another box's mask: the union cannot make the face, nothing joined
    out, _ = join_pieces([cross | quarters[3], quarters[0], quarters[1], quarters[2] | side],
                         RepairContext(cap.depth, cap.camera, Catalogue()))
    assert max(mask_iou(m, face) for m in out) < 0.9


def _two_cut_stacked_faces(step: float):
    """Two 23x25 faces stacked (the upper one `step` m nearer the camera) and a box beside them;
    the segmenter cut both down one column and merged their left parts (17 cm wide) into one
    17x50 mask: the size of an upright long box's face."""
    scene = Scene(Shelf(), (box("low", -0.05, 0.0, 0.23, 0.25, front=0.04),
                            box("up", -0.05, 0.25, 0.23, 0.25, front=0.04 - step),
                            box("side", 0.30, 0.0, 0.23, 0.25)))
    cap = cast(scene)
    low, up, side = _front(cap, 1), _front(cap, 2), _front(cap, 3)
    cols = np.arange(low.shape[1])[None, :]
    xs = np.nonzero(low)[1]
    cut = int(round(xs.min() + 0.17 / 0.23 * (np.ptp(xs) + 1)))
    merged = (low | up) & (cols < cut)
    return cap, low, up, side, merged, low & (cols >= cut), up & (cols >= cut)


def test_a_type_face_mask_across_a_depth_step_whose_parts_complete_two_pieces_is_two_boxes():
    cat = Catalogue()
    cap, low, up, side, merged, low_r, up_r = _two_cut_stacked_faces(0.013)
    assert cat.matches(*_size(merged, cap))          # the merged mask reads as a type face
    out, _, notes = apply_catalogue([merged, low_r, up_r, side], cap.depth, cap.camera, cap.rgb, cat)
    assert len(out) == 3, notes
    assert max(mask_iou(m, low) for m in out) > 0.9 and max(mask_iou(m, up) for m in out) > 0.9, notes
    assert any("type-face mask" in n and "depth step" in n for n in notes), notes
    # only one part has a piece to complete: not split (it may be a long box with a label)
    out, _, _ = apply_catalogue([merged, low_r, side], cap.depth, cap.camera, cap.rgb, cat)
    assert len(out) == 3 and any(mask_iou(m, merged) > 0.99 for m in out)
    # no depth step through it (one flat front): the type face stays as it is
    cap, low, up, side, merged, low_r, up_r = _two_cut_stacked_faces(0.0)
    out, _, _ = apply_catalogue([merged, low_r, up_r, side], cap.depth, cap.camera, cap.rgb, cat)
    assert any(mask_iou(m, merged) > 0.99 for m in out)


def _size(mask: np.ndarray, cap) -> tuple[float, float]:
    from shelfpick.perception.faces import measure_front

    f = measure_front(mask, cap.depth, cap.camera)
    return f.width, f.height


def test_a_tape_band_merged_with_the_face_above_is_given_back_to_its_face():
    # two flush 31x23 faces stacked; a vertical tape band down the lower one was merged with the
    # upper face (a T: no type face) and the lower face is left as two pieces beside the band
    cat = Catalogue()
    scene = Scene(Shelf(), (box("low", -0.05, 0.0, 0.31, 0.23), box("up", -0.05, 0.23, 0.31, 0.23),
                            box("side", 0.30, 0.0, 0.20, 0.20)))
    cap = cast(scene)
    low, up, side = _front(cap, 1), _front(cap, 2), _front(cap, 3)
    cols = np.arange(low.shape[1])[None, :]
    xs = np.nonzero(low)[1]
    cx, hw = int(np.median(xs)), int(0.06 * np.ptp(xs))
    band = low & (np.abs(cols - cx) <= hw)
    left, right = low & (cols < cx - hw), low & (cols > cx + hw)
    assert not cat.matches(*_size(up | band, cap))
    out, _, notes = apply_catalogue([up | band, left, right, side], cap.depth, cap.camera, cap.rgb, cat)
    assert len(out) == 3, notes
    assert max(mask_iou(m, low) for m in out) > 0.9 and max(mask_iou(m, up) for m in out) > 0.9, notes
    assert any("pieces' rectangle" in n for n in notes), notes
    # one piece only (the other taken by the side box's mask): the T is left as it is
    out, _, _ = apply_catalogue([up | band, left, right | side], cap.depth, cap.camera, cap.rgb, cat)
    assert any(mask_iou(m, up | band) > 0.99 for m in out)


def _seam_under(upper: np.ndarray, faces: np.ndarray, rgb: np.ndarray, colour=(150, 115, 80)) -> None:
    """Paint a 2 px seam line under `upper` over `faces` (where two flush boxes meet)."""
    rows = np.flatnonzero(upper.any(axis=1))
    band = np.zeros_like(upper)
    band[rows[-1]:rows[-1] + 2] = True
    rgb[band & faces] = colour


def test_a_faint_seam_splits_a_mask_into_exactly_two_type_faces():
    # two flush 31x23 faces of one colour (a 31x46 mask, far off every type face) with a seam one
    # grey level darker: too faint for a split in general (evidence < 1), enough for one that
    # leaves exactly two type faces (`weak_evidence`)
    scene = Scene(Shelf(), (box("low", -0.10, 0.0, 0.31, 0.23), box("high", -0.10, 0.23, 0.31, 0.23),
                            box("side", 0.25, 0.0, 0.23, 0.25)))
    cap = cast(scene)
    low, high, side = _front(cap, 1), _front(cap, 2), _front(cap, 3)
    rgb = cap.rgb.copy()
    rgb[low | high] = (180, 140, 95)
    _seam_under(high, low | high, rgb, (179, 139, 94))
    out, notes = split_faces([low | high, side], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))
    assert len(out) == 3, notes
    assert max(mask_iou(m, low) for m in out) > 0.9 and max(mask_iou(m, high) for m in out) > 0.9
    # the rule off (a seam must score 1): not split; no seam at all: not split either
    strict = RepairContext(cap.depth, cap.camera, Catalogue(weak_evidence=1.0), rgb)
    assert len(split_faces([low | high, side], strict)[0]) == 2
    rgb[low | high] = (180, 140, 95)
    assert len(split_faces([low | high, side], RepairContext(cap.depth, cap.camera, Catalogue(), rgb))[0]) == 2


def test_the_catalogue_share_is_by_area_so_a_face_in_many_pieces_does_not_switch_it_off():
    # a 50x17 face cut in four by a tape cross (whose pixels no mask claims) beside one 23x25
    # face: one type face in five masks (under `min_share` by count), but most of the area
    scene = Scene(Shelf(), (box("long", -0.2, 0.0, 0.50, 0.17), box("side", 0.25, 0.0, 0.23, 0.25)))
    cap = cast(scene)
    lng, side = _front(cap, 1), _front(cap, 2)
    ys, xs = np.nonzero(lng)
    cy, cx = int(np.median(ys)), int(np.median(xs))
    rows, cols = np.arange(lng.shape[0])[:, None], np.arange(lng.shape[1])[None, :]
    cross = lng & ((np.abs(rows - cy) <= 2) | (np.abs(cols - cx) <= 3))
    quarters = [lng & ~cross & (a * (rows - cy) > 0) & (b * (cols - cx) > 0) for a in (-1, 1) for b in (-1, 1)]
    out, _, notes = apply_catalogue(quarters + [side], cap.depth, cap.camera, cap.rgb, Catalogue())
    assert len(out) == 2, notes
    assert max(mask_iou(m, lng) for m in out) > 0.95 and max(mask_iou(m, side) for m in out) > 0.99


def test_the_rest_of_an_l_cut_is_split_into_its_row_of_faces():
    # three flush cubes of one colour (faint seams) merged with the left half of the long box on
    # the floor beside them: an L that no first split can cut; the L-cut gives the long box its
    # half back, and the rest (20x60) is then cut into the three cubes
    scene = Scene(Shelf(), (box("c0", -0.25, 0.0, 0.20, 0.20), box("c1", -0.25, 0.20, 0.20, 0.20),
                            box("c2", -0.25, 0.40, 0.20, 0.20), box("long", 0.10, 0.0, 0.50, 0.17),
                            box("o1", 0.0, 0.17, 0.23, 0.25), box("o2", 0.25, 0.17, 0.20, 0.20)))
    cap = cast(scene)
    c0, c1, c2, lng, o1, o2 = (_front(cap, k) for k in range(1, 7))
    stack = c0 | c1 | c2
    rgb = cap.rgb.copy()
    rgb[stack] = (180, 140, 95)
    for upper in (c1, c2):
        _seam_under(upper, stack, rgb)
    cols = np.arange(lng.shape[1])[None, :]
    xs = np.nonzero(lng)[1]
    cut = int(xs.min() + 0.55 * np.ptp(xs))
    ell, rest = stack | (lng & (cols < cut)), lng & (cols >= cut)
    out, _, notes = apply_catalogue([ell, rest, o1, o2], cap.depth, cap.camera, rgb, Catalogue())
    assert any("L-shaped" in n for n in notes), notes
    assert len(out) == 6, notes
    for g in (c0, c1, c2, lng, o1, o2):
        assert max(mask_iou(m, g) for m in out) > 0.9, notes


def _halves_of_two_cubes(seam: bool):
    """Two stacked 20x20 cubes of one colour, each cut down the middle by the segmenter and the
    halves merged across the cubes' seam (two 10x40 masks), and a 31x25 face beside them."""
    scene = Scene(Shelf(), (box("low", -0.10, 0.0, 0.20, 0.20), box("up", -0.10, 0.20, 0.20, 0.20),
                            box("side", 0.22, 0.0, 0.31, 0.25)))
    cap = cast(scene)
    low, up, side = (_front(cap, k) for k in (1, 2, 3))
    rgb = cap.rgb.copy()
    rgb[low | up] = (180, 140, 95)
    if seam:
        _seam_under(up, low | up, rgb)
    cols = np.arange(low.shape[1])[None, :]
    cx = int(np.median(np.nonzero(low)[1]))
    return cap, rgb, low, up, side, (low | up) & (cols < cx), (low | up) & (cols >= cx)


def test_masks_that_are_no_type_faces_are_re_cut_along_their_seams_into_type_faces():
    cap, rgb, low, up, side, left, right = _halves_of_two_cubes(seam=True)
    cat = Catalogue()
    assert not cat.matches(*_size(left, cap)) and not cat.matches(*_size(right, cap))
    out, _, notes = apply_catalogue([left, right, side], cap.depth, cap.camera, rgb, cat)
    assert len(out) == 3, notes
    for g in (low, up, side):
        assert max(mask_iou(m, g) for m in out) > 0.95, notes
    assert any("re-cut 2 masks" in n for n in notes), notes
    # no seam between the cubes: nothing says where to cut, the halves stay
    cap, rgb, low, up, side, left, right = _halves_of_two_cubes(seam=False)
    out, _, _ = apply_catalogue([left, right, side], cap.depth, cap.camera, rgb, cat)
    assert any(mask_iou(m, left) > 0.99 for m in out) and any(mask_iou(m, right) > 0.99 for m in out)


def test_a_label_beside_re_cut_faces_is_joined_to_its_face_afterwards():
    # two stacked 23x31 faces cut down the middle, halves merged (two 12x62 masks: no type face,
    # and too long to be part of one, so the label on the lower face joins neither before)
    scene = Scene(Shelf(), (box("low", -0.10, 0.0, 0.23, 0.31), box("up", -0.10, 0.31, 0.23, 0.31),
                            box("side", 0.22, 0.0, 0.31, 0.25)))
    cap = cast(scene)
    low, up, side = (_front(cap, k) for k in (1, 2, 3))
    rgb = cap.rgb.copy()
    rgb[low | up] = (180, 140, 95)
    _seam_under(up, low | up, rgb)
    rows, cols = np.arange(low.shape[0])[:, None], np.arange(low.shape[1])[None, :]
    ys, xs = np.nonzero(low)
    cy, cx = int(np.median(ys)), int(np.median(xs))
    left, right = (low | up) & (cols < cx), (low | up) & (cols >= cx)
    label = low & (np.abs(rows - cy) <= 6) & (cols >= cx) & (cols < cx + 14)
    out, _, notes = apply_catalogue([left, right & ~label, label, side], cap.depth, cap.camera, rgb, Catalogue())
    assert len(out) == 3, notes
    for g in (low, up, side):
        assert max(mask_iou(m, g) for m in out) > 0.95, notes
    assert notes[-1].startswith("joined"), notes


def test_a_piece_inside_a_mask_on_its_plane_is_given_to_it_but_a_box_in_front_is_not():
    # an upright 17x50 face whose mask also took ~5 cm of the cube below (17x55: no type face, so
    # no join explains the tape band inside it), and the band as a separate piece
    cat = Catalogue()
    scene = Scene(Shelf(), (box("cube", -0.10, 0.0, 0.20, 0.20), box("long", -0.10, 0.20, 0.17, 0.50),
                            box("side", 0.22, 0.0, 0.31, 0.25),
                            box("small", -0.10, 0.40, 0.10, 0.06, d=0.05, front=-0.04)))
    cap = cast(scene)
    cube, lng, side, small = (_front(cap, k) for k in (1, 2, 3, 4))
    rows, cols = np.arange(cube.shape[0])[:, None], np.arange(cube.shape[1])[None, :]
    strip = cube & (rows < np.flatnonzero(cube.any(axis=1))[0] + 15)
    ys, xs = np.nonzero(lng & (rows > np.flatnonzero(small.any(axis=1))[-1] + 12))
    cy, cx = int(np.median(ys)), int(np.median(xs))
    band = lng & (np.abs(rows - cy) <= 8) & (np.abs(cols - cx) <= 16)
    host = (lng | strip) & ~band
    assert not cat.matches(*_size(host, cap)) and not cat.matches(*_size(band, cap))
    out, notes = absorb_enclosed([host, band, small, cube & ~strip, side],
                                 RepairContext(cap.depth, cap.camera, cat))
    assert len(out) == 4, notes
    assert any(mask_iou(m, host | band) > 0.99 for m in out), notes
    # the small box 4 cm in front of the face, surrounded by it in the image, stays a box
    assert any(mask_iou(m, small) > 0.99 for m in out), notes


def test_faces_of_boxes_deeper_than_the_shelf_are_no_type_faces():
    # in a 30 cm shelf the 50x17x17 box never shows its 17x17 end (50 cm deep; boxes stick out
    # 5 cm at most): a 17x50 face cut in three by two tape bands is three pieces to join, not boxes
    cat = Catalogue().within(0.30)
    assert (0.17, 0.17) not in cat.faces
    assert (0.17, 0.5) in cat.faces and (0.23, 0.25) in cat.faces and (0.2, 0.2) in cat.faces
    assert (0.23, 0.25) not in Catalogue().within(0.30, overhang=0.0).faces
    assert Catalogue().within(None) == Catalogue() and (0.17, 0.17) in Catalogue().within(0.6).faces
    scene = Scene(Shelf(), (box("long", -0.10, 0.0, 0.17, 0.50), box("side", 0.22, 0.0, 0.20, 0.20)))
    cap = cast(scene)
    lng, side = _front(cap, 1), _front(cap, 2)
    rows = np.arange(lng.shape[0])[:, None]
    ys = np.nonzero(lng)[0]
    cuts = [int(ys.min() + np.ptp(ys) * f) for f in (1 / 3, 2 / 3)]
    band = np.zeros_like(lng)
    for c in cuts:
        band |= lng & (np.abs(rows - c) <= 2)
    pieces = [lng & ~band & (rows < cuts[0]), lng & ~band & (rows > cuts[0]) & (rows < cuts[1]),
              lng & ~band & (rows > cuts[1])]
    out, _, notes = apply_catalogue(pieces + [side], cap.depth, cap.camera, cap.rgb, cat)
    assert len(out) == 2, notes
    assert max(mask_iou(m, lng) for m in out) > 0.95 and max(mask_iou(m, side) for m in out) > 0.99
    # every box shape allowed (a deep shelf): the three 17x17 "end faces" stay three boxes
    out, _, _ = apply_catalogue(pieces + [side], cap.depth, cap.camera, cap.rgb, Catalogue())
    assert len(out) == 4


def test_two_pieces_are_not_joined_across_a_gap_the_depth_sees_through():
    """Two 20x17 cm fronts side by side 4 cm apart, the right one's mask holding the gap (a mask
    that had covered both, cut): joined they would be a 44x17 face that fits inside a 50x17 one,
    but the gap's pixels lie on the back wall, far behind their plane. Flush, they are joined."""
    def pieces(gap: float):
        scene = Scene(Shelf(), (box("l", -0.10 - gap / 2, 0.0, 0.20, 0.17),
                                box("r", 0.10 + gap / 2, 0.0, 0.20, 0.17)))
        cap = cast(scene)
        left, right = _front(cap, 1), _front(cap, 2)
        rows, cols = np.flatnonzero(right.any(axis=1)), np.flatnonzero(left.any(axis=0))
        between = np.zeros_like(right)
        between[rows[0]:rows[-1] + 1, cols[-1] + 1:np.flatnonzero(right.any(axis=0))[0]] = True
        return cap, left, right | (between & ~left)

    cap, left, right = pieces(0.04)
    out, notes = join_pieces([left, right], RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 2, notes
    cap, left, right = pieces(0.0)
    out, notes = join_pieces([left, right], RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 1 and any("joined" in n for n in notes), notes


def test_a_face_cut_into_a_row_of_pieces_is_joined_as_a_chain_not_with_the_cube_beside_it():
    """A 50x17 face cut by its tape and a label into a row (labels 31004): a left part, the tape
    (reaching over the right part's top left), an upper and a lower right piece, and a 20x20 cube
    flush beside it. The upper piece (the smallest) makes no type face with either neighbour, nor
    with both; it used to take the cube as a chance type face, a 49x17 face across the seam. The
    whole row, reached through the tape, is one type face: joined as a chain, the cube stays."""
    scene = Scene(Shelf(), (box("long", -0.10, 0.0, 0.50, 0.17), box("cube", 0.254, 0.0, 0.20, 0.20)))
    cap = cast(scene)
    face, cube = _front(cap, 1), _front(cap, 2)
    ys, xs = np.nonzero(face)
    cols, rows = np.arange(face.shape[1])[None, :], np.arange(face.shape[0])[:, None]
    x0, w, top = xs.min(), np.ptp(xs) + 1, rows < ys.min() + 0.45 * (np.ptp(ys) + 1)
    left = face & (cols < x0 + 0.42 * w)
    upper = face & (cols >= x0 + 0.70 * w) & top
    lower = face & (cols >= x0 + 0.50 * w) & ~top
    tape = face & ~left & ~upper & ~lower
    out, notes = join_pieces([left, tape, upper, lower, cube], RepairContext(cap.depth, cap.camera, Catalogue()))
    assert len(out) == 2, notes
    assert max(mask_iou(m, face) for m in out) > 0.95, notes
    assert max(mask_iou(m, cube) for m in out) > 0.95, notes
