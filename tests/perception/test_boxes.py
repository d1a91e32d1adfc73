"""Front faces measured in metres, boxes from them, and a scene that can stand."""
from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from shelfpick.perception.boxes import CONTRADICTION, boxes_from_masks, distance_from_box_size, flag_contradicted, make_valid
from shelfpick.perception.faces import _rect_long_edge, measure_front
from shelfpick.perception.evaluation.truth import front_face_masks
from shelfpick.perception.scene import Box, Scene, Shelf
from synth_frames import SMALL_CAMERA, box, cast


def test_long_edge_angle_not_opencv_convention():
    for angle in (-30.0, -10.0, 0.0, 12.0, 40.0):
        a = math.radians(angle)
        ex, ez = np.array([math.cos(a), math.sin(a)]), np.array([-math.sin(a), math.cos(a)])
        pts = np.array([s * 150 * ex + t * 60 * ez for s in (-1, 1) for t in (-1, 1)])
        _, w, h, got = _rect_long_edge(pts)
        assert abs(got - angle) < 0.5 and abs(w - 300) < 1 and abs(h - 120) < 1
    # a tall face: width is the short horizontal edge, angle stays near 0
    pts = np.array([[-40, -200], [40, -200], [40, 200], [-40, 200]], float)
    _, w, h, got = _rect_long_edge(pts)
    assert abs(got) < 1e-6 and abs(w - 80) < 1 and abs(h - 400) < 1


def test_front_face_is_measured_within_a_centimetre():
    b = box("a", 0.05, 0.0, 0.30, 0.22, front=0.04)
    scene = Scene(Shelf(), (b,))
    cap = cast(scene, noise=0.001)
    face = measure_front(front_face_masks(scene, cap)["a"], cap.depth, cap.camera)
    assert face is not None
    fc = np.asarray(b.front_center)
    assert np.linalg.norm(np.asarray(face.center) - fc) < 0.01
    assert abs(face.width - 0.30) < 0.01 and abs(face.height - 0.22) < 0.01
    assert face.angle == 0.0


def test_tilted_box_angle_about_shelf_y():
    a = math.radians(15.0)
    q = (math.cos(-a / 2), 0.0, math.sin(-a / 2), 0.0)   # rotation about y by -15 deg: x toward +z
    b = Box("t", (0.30, 0.2, 0.12), (0.0, 0.12, 0.20), q)
    scene = Scene(Shelf(), (b,))
    cap = cast(scene, camera=SMALL_CAMERA)
    face = measure_front(front_face_masks(scene, cap)["t"], cap.depth, cap.camera)
    assert abs(face.angle - 15.0) < 1.5
    assert abs(face.width - 0.30) < 0.012 and abs(face.height - 0.12) < 0.012


def test_boxes_carry_unknown_depth_placeholder_and_labels():
    scene = Scene(Shelf(), (box("a", -0.2, 0, 0.3, 0.25, front=0.0), box("b", 0.2, 0, 0.25, 0.2, front=0.12)))
    cap = cast(scene)
    masks = [cap.masks == 1, cap.masks == 2]
    boxes, ordered, faces, warns = boxes_from_masks(masks, cap.depth, cap.camera, scene.shelf)
    assert [b.id for b in boxes] == ["b0", "b1"] and [b.mask_label for b in boxes] == [1, 2]
    assert all(not b.depth_known for b in boxes)
    assert boxes[0].size[1] == pytest.approx(0.25)
    assert boxes[1].size[1] == pytest.approx(0.30 - boxes[1].front_y, abs=1e-6)   # up to the back wall
    assert abs(boxes[1].front_y - 0.12) < 0.01


def _b(bid, x, z, w=0.2, h=0.2, y=0.0, d=0.25):
    return Box(bid, (w, d, h), (x, y + d / 2, z + h / 2), depth_known=False)


def test_make_valid_snaps_gaps_pushes_overlaps_and_drops_hanging_boxes():
    shelf = Shelf()
    boxes = [_b("floor", 0.0, 0.012),            # 1.2 cm above the floor: snapped down
             _b("on", 0.0, 0.19),                # 1 cm into the box below: pushed up
             _b("hang", -0.3, 0.30),             # nothing below: dropped to the floor
             _b("wall", 0.45, 0.0)]              # sticks out of the right wall
    out, notes = make_valid(boxes, shelf)
    by = {b.id: b for b in out}
    assert min(c[2] for c in by["floor"].corners()) == pytest.approx(0.0, abs=1e-6)
    assert min(c[2] for c in by["on"].corners()) == pytest.approx(by["floor"].top_z, abs=1e-3)
    assert min(c[2] for c in by["hang"].corners()) == pytest.approx(0.0, abs=1e-6)
    assert max(c[0] for c in by["wall"].corners()) <= shelf.width / 2 + 1e-6
    text = " ".join(notes)
    assert "floor: lowered" in text and "on: pushed up" in text and "hang: hung" in text
    assert "wall: moved" in text
    Scene(shelf, tuple(out)).check_bounds(tol=1e-9)


def test_make_valid_pushes_side_by_side_overlap_apart_and_shrinks_placeholder():
    out, notes = make_valid([_b("l", -0.1, 0.0), _b("r", 0.095, 0.0), _b("deep", -0.35, 0.0, y=0.15, d=0.25)],
                            Shelf())
    by = {b.id: b for b in out}
    assert max(c[0] for c in by["l"].corners()) <= min(c[0] for c in by["r"].corners()) + 1e-6
    assert max(c[1] for c in by["deep"].corners()) == pytest.approx(0.30, abs=1e-6)
    assert by["deep"].front_y == pytest.approx(0.15)
    assert any("pushed apart" in n for n in notes)


def test_distance_from_known_box_size():
    b = box("a", 0.0, 0.15, 0.30, 0.20, front=0.0)
    cap = cast(Scene(Shelf(), (b,)))
    d = distance_from_box_size([cap.masks == 1], cap.camera, (0.30, 0.20))
    true = 0.0 - cap.camera.position[1]
    assert abs(d - true) < 0.04


def test_box_measured_partly_inside_the_box_below_rests_on_it():
    """A face measured 3.5 cm too low overlaps the box under it by more than the snap
    distance: it is pushed up onto that box, never dropped through it to a lower one."""
    from shelfpick.perception.boxes import make_valid
    from shelfpick.perception.scene import Box, Shelf

    bottom = Box("b0", (0.5, 0.25, 0.17), (0.0, 0.125, 0.085), depth_known=False)
    middle = Box("b1", (0.5, 0.25, 0.12), (0.0, 0.125, 0.17 + 0.06), depth_known=False)
    top = Box("b2", (0.23, 0.25, 0.16), (0.0, 0.125, 0.29 - 0.035 + 0.08), depth_known=False)
    out, notes = make_valid([bottom, middle, top], Shelf())
    placed = {b.id: b for b in out}
    assert placed["b2"].position[2] - 0.08 == pytest.approx(0.29, abs=1e-3)
    assert any("b2" in n and "pushed up" in n for n in notes)


def test_faces_that_cannot_be_on_the_shelf_are_dropped_with_the_reason():
    """A wall, the floor or a region near the horizon in a photo back-projects to faces metres
    wide or far away; kept, make_valid would stack every other box on top of them."""
    from shelfpick.perception.boxes import not_a_front
    from shelfpick.perception.faces import FrontFace

    shelf = Shelf()

    def face(center, w=0.2, h=0.2):
        return FrontFace(center=center, width=w, height=h, angle=0.0, yaw=0.0, distance=1.0,
                         pixels=100, rect_px=((0, 0), (1, 1), 0))

    assert not_a_front(face((0.1, 0.02, 0.3)), shelf) == ""
    assert not_a_front(face((0.0, 0.0, 0.1), w=0.55, h=0.17), shelf) == ""
    assert "larger than" in not_a_front(face((0.0, 0.1, 0.5), w=13463.9, h=351.1), shelf)
    assert "larger than" in not_a_front(face((0.0, 0.1, 0.5), w=0.4, h=1.9), shelf)
    assert "in front of the shelf" in not_a_front(face((0.0, -813.0, 0.3)), shelf)
    assert "back wall" in not_a_front(face((0.0, 0.6, 0.3)), shelf)
    assert "outside the shelf" in not_a_front(face((0.9, 0.1, 0.3)), shelf)
    assert "outside the shelf" in not_a_front(face((0.0, 0.1, 2.2)), shelf)
    assert "not finite" in not_a_front(face((float("nan"), 0.1, 0.3)), shelf)
    assert "smaller than" in not_a_front(face((0.0, 0.1, 0.3), w=0.01), shelf)
    # a box overhanging the side by a few cm stays
    assert not_a_front(face((0.52, 0.1, 0.3)), shelf) == ""


def _turned(bid, x, z, yaw_deg=0.0, lean_deg=0.0, w=0.2, h=0.2, d=0.25, front=0.0):
    """An unknown-depth box whose front face centre is (x, front, z), turned about z (yaw) and
    about y (leaning sideways), as perception builds it from a measured face."""
    from shelfpick.perception.faces import face_axes, FrontFace
    from shelfpick.perception.geometry import matrix_to_quat

    f = FrontFace(center=(x, front, z), width=w, height=h, angle=lean_deg, yaw=yaw_deg, distance=1.0,
                  pixels=100, rect_px=((0, 0), (1, 1), 0))
    rot = face_axes(f)
    pos = np.asarray(f.center) + rot[:, 1] * d / 2
    return Box(bid, (w, d, h), tuple(float(v) for v in pos), matrix_to_quat(rot), depth_known=False)


def test_sweep_gives_the_shifts_at_which_boxes_meet():
    from shelfpick.perception.contact import sweep

    a, b = _b("a", 0.0, 0.2), _b("b", 0.0, 0.0)        # a on b, both 20 cm cubes
    lo, hi = sweep(a, b, (0.0, 0.0, 1.0))
    assert lo == pytest.approx(-0.4) and hi == pytest.approx(0.0)
    assert sweep(_b("c", 0.3, 0.2), b, (0.0, 0.0, 1.0)) is None   # beside it: never meet going up


def test_turned_neighbours_whose_unseen_backs_cross_are_not_stacked():
    """Two boxes side by side turned towards each other (yaw -16 / +14 deg), faces 3.5 cm apart:
    their placeholder depths cross behind the faces. Neither face may move: on axis-aligned bounds
    the right one was pushed up 20 cm onto the left (judge shelf u13)."""
    left = _turned("l", 0.0, 0.1, yaw_deg=-16.0)
    right = _turned("r", 0.235, 0.104, yaw_deg=14.0)      # 4 mm above the floor: the gap closes
    from shelfpick.perception.contact import sweep
    assert sweep(left, right, (0.0, 0.0, 1.0)) is not None     # the premise: the boxes do overlap
    out, notes = make_valid([left, right], Shelf())
    by = {b.id: b for b in out}
    assert by["l"].front_center[2] == pytest.approx(0.1, abs=1e-3)
    assert by["r"].front_center[2] == pytest.approx(0.1, abs=1e-3)
    assert not any("pushed up" in n for n in notes)


def test_leaning_box_beside_a_taller_one_is_not_pushed_up_by_its_bounds():
    """A 31x25 face leaning 24 deg sideways rests on a 23 cm box, its raised end passing 7 mm
    over the corner of a 31 cm box beside it: its axis-aligned bounds reach 9 cm into that box
    and 8 cm below its top, so it was pushed up 8 cm (judge shelf u07); its shape does not."""
    from shelfpick.perception.contact import sweep

    low = _b("low", -0.2, 0.0, w=0.31, h=0.232)
    tall = _b("tall", 0.0, 0.0, w=0.2, h=0.31)
    lean = _turned("lean", -0.2, 0.3, lean_deg=24.0, w=0.31, h=0.25)
    zmin = min(c[2] for c in lean.corners())
    lean = Box("lean", lean.size, (lean.position[0], lean.position[1], lean.position[2] - zmin + 0.232),
               lean.orientation, depth_known=False)
    # the premise: bounds overlap the tall box in x and in z, the shapes pass each other
    assert max(c[0] for c in lean.corners()) > min(c[0] for c in tall.corners()) + 0.05
    assert sweep(lean, tall, (0.0, 0.0, 1.0))[1] < 0
    out, notes = make_valid([low, tall, lean], Shelf())
    by = {b.id: b for b in out}
    assert min(c[2] for c in by["lean"].corners()) == pytest.approx(0.232, abs=3e-3)
    assert not any("lean: pushed up" in n for n in notes)


# --- make_valid's output is a scene the planner's sample worlds can build (issue 31: two held-out
# --- shelves refused with "no draw of sample can be built: box ... overlaps ...")

def _upright(i: str, x: float, z0: float, w: float, h: float, hidden: bool = False) -> Box:
    extra = {"perceived": {"top_hidden": True}} if hidden else {"perceived": {}}
    return Box(i, (w, 0.25, h), (x, 0.125, z0 + h / 2), (1.0, 0.0, 0.0, 0.0), None, False, 1, extra)


def _refusal(boxes: list[Box], shelf: Shelf) -> str:
    """'' when the planner builds sample world 0 of the scene, else why it refuses."""
    import warnings

    from shelfpick.perception.errors import SceneError
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.sample_worlds import build_sample

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            build_sample(Scene(shelf, tuple(boxes)), 0, 0, PhysicsConfig().for_prediction()).sim.close()
    except SceneError as exc:
        return str(exc)
    return ""


def test_a_hidden_top_support_does_not_grow_into_the_box_resting_on_it_beside():
    # b0's top edge was hidden; b2 rests on b0's seen top, b1 hangs 10 cm over b0 further left
    shelf = Shelf()
    seen = [_upright("b0", 0.0, 0.0, 0.2, 0.15, hidden=True), _upright("b2", 0.1, 0.15, 0.2, 0.2),
            _upright("b1", -0.15, 0.25, 0.2, 0.2)]
    grown = [Box("b0", (0.2, 0.25, 0.25), (0.0, 0.125, 0.125)), *seen[1:]]     # what growing b0 gave
    assert "overlap by" in _refusal(grown, shelf)
    boxes, notes = make_valid(seen, shelf)
    assert boxes[0].size[2] == pytest.approx(0.15) and boxes[2].position[2] == pytest.approx(0.25)
    assert any("would overlap b2" in n and "b1 drops instead" in n for n in notes)
    assert _refusal(boxes, shelf) == ""


def test_a_stack_taller_than_the_shelf_is_cut_to_fit_and_said():
    shelf = Shelf()
    seen = [_upright("b0", 0.0, 0.0, 0.2, 0.5), _upright("b1", 0.0, 0.5, 0.2, 0.5), _upright("b2", 0.0, 1.0, 0.2, 0.62)]
    assert "overlaps the shelf" in _refusal(seen, shelf)
    boxes, notes = make_valid(seen, shelf)
    top = max(c[2] for c in boxes[2].corners())
    assert top == pytest.approx(shelf.height) and boxes[2].size[2] == pytest.approx(0.60)
    assert any(n.startswith("b2: its stack reaches 1.620 m") and "cannot all be right" in n for n in notes)
    assert _refusal(boxes, shelf) == ""


def test_side_by_side_faces_overlapping_past_snap_are_parted_and_said():
    shelf = Shelf()
    seen = [_upright("b0", 0.0, 0.0, 0.2, 0.2), _upright("b1", 0.13, 0.0, 0.2, 0.2)]     # 7 cm into each other
    assert "overlap by" in _refusal(seen, shelf)
    boxes, notes = make_valid(seen, shelf)
    assert boxes[1].position[0] - boxes[0].position[0] == pytest.approx(0.2, abs=1e-3)
    assert any("pushed apart sideways by 7.0 cm" in n and "cannot all be right" in n for n in notes)
    assert _refusal(boxes, shelf) == ""
    # a face in front of another box's placeholder depth is not parted (one box behind the other)
    back = Box("b1", (0.2, 0.15, 0.2), (0.13, 0.2, 0.1), (1.0, 0.0, 0.0, 0.0), None, False, 1, {"perceived": {}})
    boxes, notes = make_valid([_upright("b0", 0.0, 0.0, 0.2, 0.2), back], shelf)
    assert boxes[1].position[0] == pytest.approx(0.13) and not any("cannot all be right" in n for n in notes)
    assert _refusal(boxes, shelf) == ""


def test_a_box_sunk_into_a_long_box_below_is_lifted_not_pushed_sideways():
    # b1 measured 2 cm into the long box under it, 12 cm into it sideways: up is the short way out
    shelf = Shelf()
    boxes, notes = make_valid([_upright("b0", 0.25, 0.0, 0.5, 0.17), _upright("b1", 0.02, 0.15, 0.2, 0.2)], shelf)
    assert boxes[1].position[0] == pytest.approx(0.02) and boxes[0].position[0] == pytest.approx(0.25)
    assert boxes[1].position[2] == pytest.approx(0.27, abs=2e-3)
    assert not any("cannot all be right" in n for n in notes)


def test_unexplained_matter_stand_ins_are_never_pushed_past_snap():
    # '~' boxes stand in for unexplained matter while boxes rest (pipeline._supports): a box 7 cm
    # into one moves nothing sideways (37ef93f pushed them apart, and a box above went up 13 cm)
    shelf = Shelf()
    stand_in = Box("~u0.0", (0.2, 0.25, 0.2), (0.13, 0.125, 0.1))
    boxes, notes = make_valid([_upright("b0", 0.0, 0.0, 0.2, 0.2), stand_in], shelf)
    assert boxes[0].position[0] == pytest.approx(0.0) and boxes[1].position[0] == pytest.approx(0.13)
    assert not any("pushed apart" in n for n in notes)


# --- a face measured a few cm into a lower side neighbour is beside it, not on it (issue 31,
# --- make_valid_jitter.py --sigma 0.015: tuning shelves 31000, 31012, 31026 refused)

def _seen(i: str, x0: float, x1: float, z0: float, h: float, front: float = 0.0) -> Box:
    """A perceived box: its face x0..x1 wide, from z0 up h, at `front`; a 25 cm placeholder depth."""
    return Box(i, (x1 - x0, 0.25, h), ((x0 + x1) / 2, front + 0.125, z0 + h / 2), (1.0, 0.0, 0.0, 0.0),
               None, False, 1, {"perceived": {}})


def _bottom(b: Box) -> float:
    return min(c[2] for c in b.corners())


def test_a_face_measured_into_the_column_beside_it_is_parted_not_lifted_onto_it():
    # 'top' rests on 'low'; its face was measured 4 cm too far left, into the tall 'side' column,
    # 3.7 cm in front of side's face (so the faces' slabs never meet). It was pushed up 23 cm out
    # of 'side', into 'above', which rests on 'right' (31000: b6 pushed up 14.4 cm out of b4)
    shelf = Shelf()
    seen = [_seen("side", -0.50, -0.26, 0.0, 0.40), _seen("low", -0.25, 0.25, 0.0, 0.17),
            _seen("right", 0.26, 0.50, 0.0, 0.34), _seen("top", -0.30, 0.25, 0.17, 0.17, front=-0.037),
            _seen("above", -0.24, 0.30, 0.34, 0.17)]
    boxes, notes = make_valid(seen, shelf)
    by = {b.id: b for b in boxes}
    assert not any(n.startswith("top: pushed up") for n in notes), notes
    assert _bottom(by["top"]) == pytest.approx(0.17, abs=1e-3)
    # out of 'side': moved right up to 'right' (1 cm), the rest cut off its width (its face is
    # 3 cm wider than the gap between the two columns)
    assert min(c[0] for c in by["top"].corners()) == pytest.approx(-0.26, abs=1e-3)
    assert max(c[0] for c in by["top"].corners()) == pytest.approx(0.26, abs=1e-3)
    assert any(n.startswith("top: moved 1.0 cm right and cut 3.0 cm narrower out of side beside it")
               and "cannot all be right" in n for n in notes), notes
    assert _bottom(by["above"]) == pytest.approx(0.34, abs=1e-3)
    assert _refusal(boxes, shelf) == ""


def test_a_box_beside_a_taller_one_stays_on_the_floor_under_its_stack():
    # 'a' was measured 1 cm above the floor; pushing its neighbours apart leaves it 1.75 cm into
    # the taller 'b' sideways: it was pushed up 24 cm out of 'b' and floated with 'a2' on it
    # (31026: b0 pushed up 25.3 cm out of b1, and b4 on it dropped under it to the floor)
    shelf = Shelf()
    seen = [_seen("a", -0.49, -0.25, 0.01, 0.25), _seen("a2", -0.49, -0.25, 0.26, 0.25),
            _seen("b", -0.26, -0.01, 0.0, 0.25), _seen("c", -0.04, 0.46, 0.0, 0.17)]
    boxes, notes = make_valid(seen, shelf)
    by = {b.id: b for b in boxes}
    assert not any(n.startswith("a: pushed up") for n in notes), notes
    assert _bottom(by["a"]) == pytest.approx(0.0, abs=1e-3)
    assert _bottom(by["a2"]) == pytest.approx(0.25, abs=1e-3)
    assert max(c[0] for c in by["a"].corners()) <= min(c[0] for c in by["b"].corners()) + 1e-3
    assert _refusal(boxes, shelf) == ""


def test_a_box_measured_deep_into_boxes_on_both_sides_is_cut_to_the_gap():
    # between two taller columns, 4 cm into each, 3.7 cm in front of them: neither is under it and
    # no sideways move parts it from both: it is cut to the gap, rests on the floor, and says so
    shelf = Shelf()
    seen = [_seen("l", -0.40, -0.20, 0.0, 0.40), _seen("r", 0.20, 0.40, 0.0, 0.40),
            _seen("mid", -0.24, 0.24, 0.01, 0.20, front=-0.037)]
    boxes, notes = make_valid(seen, shelf)
    by = {b.id: b for b in boxes}
    assert _bottom(by["mid"]) == pytest.approx(0.0, abs=1e-3)
    assert by["mid"].position[0] == pytest.approx(0.0) and by["mid"].size[0] == pytest.approx(0.40, abs=1e-3)
    assert any(n.startswith("mid: cut 8.0 cm narrower out of l/r beside it") for n in notes), notes
    assert _refusal(boxes, shelf) == ""


def test_a_face_seen_behind_another_face_that_would_hide_it_is_reported():
    """h22's labels 31015: one mask over an L of two cartons measured as its 44x41 cm rectangle,
    and a 20x20 face seen 2.6 cm behind it, wholly within it across. The camera cannot have seen
    that face there, so the scene says its faces cannot all be right (no sample world can be built from them)."""
    shelf = Shelf()
    big = _upright("b6", 0.0, 0.0, 0.44, 0.41)
    inside = Box("b7", (0.2, 0.25, 0.2), (0.08, 0.026 + 0.125, 0.15), (1.0, 0.0, 0.0, 0.0), None, False, 2,
                 {"perceived": {}})
    beside = Box("b8", (0.2, 0.25, 0.2), (0.27, 0.03 + 0.125, 0.1), (1.0, 0.0, 0.0, 0.0), None, False, 3,
                 {"perceived": {}})        # 30 % of it behind b6's face: an ordinary occlusion
    boxes, notes = make_valid([big, inside, beside], shelf)
    said = [n for n in notes if "could not have seen" in n]
    assert len(said) == 1 and said[0].startswith("b7: its face lies 2.6 cm behind b6's and 100% of it")
    assert "cannot all be right" in said[0]
    assert "overlap" in _refusal(boxes, shelf)
    # the same face 5 mm behind (one depth, an overlap of slabs) is the overlap test's, not this one's
    level = replace(inside, position=(0.08, 0.005 + 0.125, 0.15))
    assert not any("could not have seen" in n for n in make_valid([big, level], shelf)[1])


def test_a_face_behind_another_closer_than_any_box_is_deep_is_reported():
    """A face 4 cm behind another that overlaps it 6x20 cm across: the front box, at least 15 cm
    deep in every sample world, passes 11 cm through it, more than the 5 cm the worlds repair, so
    no sample world can be built from them; perceive says so first. 12 cm behind it fits and is not said."""
    from shelfpick.perception import boxes as perceived
    from shelfpick.planning.physics import PhysicsConfig

    cfg = PhysicsConfig()
    assert (perceived.MIN_BOX_DEPTH, perceived.REPAIRABLE) == (cfg.min_sample_depth, cfg.prediction_repair_tolerance)
    shelf = Shelf()
    front = _upright("b0", 0.0, 0.0, 0.3, 0.3)
    corner = Box("b1", (0.2, 0.25, 0.2), (0.19, 0.04 + 0.125, 0.1), (1.0, 0.0, 0.0, 0.0), None, False, 2,
                 {"perceived": {}})      # x 0.09-0.29, z 0-0.2: 6x20 cm of it behind b0's face
    boxes, notes = make_valid([front, corner], shelf)
    said = [n for n in notes if "would pass through" in n]
    assert len(said) == 1 and said[0].startswith("b1: its face lies 4.0 cm behind b0's, 6x20 cm of it")
    assert "overlap" in _refusal(boxes, shelf)
    far = replace(corner, position=(0.19, 0.12 + 0.125, 0.1))
    boxes, notes = make_valid([front, far], shelf)
    assert not any("cannot all be right" in n for n in notes) and _refusal(boxes, shelf) == ""


def test_a_box_moved_up_or_down_past_snap_is_a_contradiction_naming_both_faces():
    """A face measured 5 cm into the box under it, or 6 cm above any support, is no measurement
    error: make_valid still moves it so the shelf can stand, but says the faces cannot all be
    right, and flag_contradicted marks the boxes named (planning does not call a plan touching
    them safe). Within `snap` (3 cm) a move is a note only."""
    boxes = [_b("low", 0.0, 0.0), _b("into", 0.0, 0.15),          # 5 cm into 'low'
             _b("low2", -0.3, 0.0), _b("near", -0.3, 0.18),       # 2 cm into 'low2': a note only
             _b("hang", 0.3, 0.06)]                               # 6 cm above the floor
    out, notes = make_valid(boxes, Shelf())
    said = [n for n in notes if CONTRADICTION in n]
    assert any(n.startswith("into: pushed up 5.0 cm out of low") for n in said), notes
    assert any(n.startswith("hang: hung 6.0 cm in the air; dropped onto the floor") for n in said), notes
    assert any(n.startswith("near: pushed up 2.0 cm") for n in notes)
    assert not any(n.startswith("near:") for n in said)
    marked = {b.id for b in flag_contradicted(out, notes) if b.contradicted}
    assert marked == {"into", "low", "hang"}
