"""From measured front faces to boxes in the shelf frame, and a scene that can stand.

Each mask's front face is measured by `perception.faces.measure_front`. The camera
sees no depth, so boxes get `depth_known: false` and a placeholder depth behind the
measured front. `make_valid` then rests every box on the floor or on a box below
(closing small gaps, resolving small overlaps), keeps boxes inside the shelf, and
says what it moved.
"""
from __future__ import annotations

import math
import re
from dataclasses import replace

import cv2
import numpy as np

from shelfpick.perception.contact import box_corners, face_part, face_sweep, pose_memo, sweep
from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.faces import FrontFace, face_axes, measure_front
from shelfpick.perception.geometry import matrix_to_quat
from shelfpick.perception.masks import border_sides
from shelfpick.perception.scene import Box, Camera, Shelf, quat_to_matrix


def box_from_face(face: FrontFace, box_id: str, label: int, shelf: Shelf,
                  placeholder: float = 0.25) -> Box:
    """A box whose front face is the measured one and whose depth is a placeholder."""
    rot = face_axes(face)
    front_y = face.center[1]
    depth = min(placeholder, shelf.depth - front_y)
    depth = max(depth, 0.02)
    pos = np.asarray(face.center) + rot[:, 1] * depth / 2
    return Box(box_id, (face.width, depth, face.height), tuple(float(x) for x in pos),  # type: ignore[arg-type]
               matrix_to_quat(rot), None, False, label,
               {"perceived": {"angle_deg": round(face.angle, 3), "yaw_deg": round(face.yaw, 3),
                              "tilt_deg": round(face.tilt, 3), "distance": round(face.distance, 4)}})


# --------------------------------------------------------------------------
# physically valid scene
UP = (0.0, 0.0, 1.0)


def _aabb(b: Box) -> np.ndarray:
    """2x3: the lowest and highest corner coordinates of the box (its corners memoised by pose)."""
    c = box_corners(b)
    return np.stack([c.min(axis=0), c.max(axis=0)])


def _moved(b: Box, delta: np.ndarray) -> Box:
    return replace(b, position=tuple(float(p + d) for p, d in zip(b.position, delta)))  # type: ignore[arg-type]


def _overlap(a: np.ndarray, b: np.ndarray, axis: int) -> float:
    return float(min(a[1, axis], b[1, axis]) - max(a[0, axis], b[0, axis]))


def make_valid(boxes: list[Box], shelf: Shelf, snap: float = 0.03,
               min_contact: float = 0.01) -> tuple[list[Box], list[str]]:
    """Boxes resting on the floor or on each other, inside the shelf; and what was changed.

    Geometric, no physics: small gaps (<= `snap`) under a box are closed, small
    overlaps pushed apart (up, or sideways for neighbours), a box with nothing
    under it is dropped onto the nearest support below, a box measured deep into a lower
    box beside it is parted from it sideways, not lifted onto it (`_beside`), and boxes are
    clamped into the shelf. Placeholder depths shrink to fit before the back wall. The boxes' corners
    and separating axes are remembered for the call (`contact.pose_memo`).
    """
    notes: list[str] = []
    with pose_memo():
        out = [_clamp(b, shelf, notes) for b in boxes]
        out, said = _push_apart(out, snap, min_contact)
        notes += said
        out = [_clamp(b, shelf, notes) for b in out]
        out, said = _rest_on_supports(out, snap, min_contact, shelf.height, shelf.width / 2)
        notes += said
        out, said = _under_the_top(out, shelf)
        notes += said
        notes += _overlaps_left(out, shelf)
    return out, notes


# words that mark a note as a contradiction the caller reports as a warning (perceived faces that
# cannot all be right), not one more small move
CONTRADICTION = "cannot all be right"
# a deeper overlap than this between two boxes, or with the shelf, is reported (the planner's sample
# worlds repair overlaps up to 2 cm, 5 cm when they predict; their draws move each face by <= 0.5 cm)
LEFT_OVERLAP = 0.02


def _depth(a: Box, b: Box, along: tuple = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))) -> float:
    """How deep two boxes overlap: the smallest move along one of `along` that parts them (0: apart)."""
    best = np.inf
    for d in along:
        s = sweep(a, b, d)
        if s is None or not s[0] < 0 < s[1]:
            return 0.0
        best = min(best, -s[0], s[1])
    return float(best)


def _face_depth(a: Box, b: Box) -> float:
    """How deep what was measured of the two (`face_part`: the front slab where the depth is a
    placeholder) overlaps across the pull (x or z; 0 when apart in depth): a placeholder reaching a
    face behind it is for the sample worlds' depth draws to fit, not a contradiction, and two
    slabs side by side at one depth are one box's depth into each other, not a slab's."""
    return _depth(face_part(a), face_part(b), ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))


def flag_contradicted(boxes: list[Box], notes: list[str]) -> list[Box]:
    """The boxes, each one a contradiction note names (`... cannot all be right`) carrying
    `perceived.contradicted: true`, so that planning, which reads the scene file, knows which faces
    perception itself doubts (planning/contradicted.py: a plan touching one is not declared safe)."""
    said = [n for n in notes if CONTRADICTION in n]
    named = {b.id for b in boxes if any(re.search(rf"(?<![\w~]){re.escape(b.id)}(?!\w)", n) for n in said)}
    return [replace(b, extra={**b.extra, "perceived": {**(b.extra.get("perceived") or {}), "contradicted": True}})
            if b.id in named else b for b in boxes]


def _overlaps_left(boxes: list[Box], shelf: Shelf) -> list[str]:
    """A warning note for each pair of boxes still overlapping deeper than `LEFT_OVERLAP`, and each
    box still above the shelf's top: what the sample worlds would refuse to build."""
    notes = []
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            d = _face_depth(a, b)
            if d > LEFT_OVERLAP and not (a.id.startswith("~") or b.id.startswith("~")):
                notes.append(f"{a.id}/{b.id}: overlap by {d * 100:.1f} cm that make_valid could not part; "
                             f"their perceived faces {CONTRADICTION}")
        top = _aabb(a)[1, 2]
        if top > shelf.height + 1e-6:
            notes.append(f"{a.id}: reaches {top:.3f} m, above the shelf height {shelf.height:.3f} m; "
                         f"the faces of its stack {CONTRADICTION}")
    return notes + _faces_behind(boxes)


# a seen face this far behind another, and this much of it within that face across, is hidden from the
# camera by it: a face that was seen there says one of the two measured faces is wrong (an L of two
# cartons measured as its rectangle, h22's labels 31015); a face behind another and partly beside it
# is an ordinary occlusion, and faces within 1 cm in depth are the overlap test's
HIDDEN_BEHIND = 0.01
HIDDEN_SHARE = 0.75
# the planner's shallowest drawn box (`PhysicsConfig.min_sample_depth`) and the deepest overlap its
# sample worlds repair (`prediction_repair_tolerance`), restated here because perception imports no
# planning (tests/perception/test_boxes.py checks they agree): a face less than their difference behind
# another that overlaps it across by more than the second both ways is one the front box, however
# shallow, would pass through
MIN_BOX_DEPTH = 0.15
REPAIRABLE = 0.05


def _face_xz(b: Box) -> np.ndarray:
    """2x2: the lowest and highest x and z of the box's front face (its local -y side)."""
    c = box_corners(b)
    r = np.asarray(quat_to_matrix(b.orientation))
    front = c[(c - np.asarray(b.position)) @ r[:, 1] < 0][:, [0, 2]]
    return np.stack([front.min(axis=0), front.max(axis=0)])


def _faces_behind(boxes: list[Box]) -> list[str]:
    """A warning note for each perceived face behind another perceived face that the nearer one
    would hide from the camera, or that the nearer one's box would pass through (each face's
    rectangle measured once)."""
    seen = [(b, _face_xz(b), b.front_center[1]) for b in boxes if not b.depth_known and not b.id.startswith("~")]
    notes = []
    for a, fa, ya in seen:
        for b, fb, yb in seen:
            behind = yb - ya
            if behind <= HIDDEN_BEHIND:
                continue
            across = np.clip(np.minimum(fa[1], fb[1]) - np.maximum(fa[0], fb[0]), 0.0, None)
            share = float(across.prod() / max(np.prod(fb[1] - fb[0]), 1e-9))
            if share >= HIDDEN_SHARE:
                notes.append(f"{b.id}: its face lies {behind * 100:.1f} cm behind {a.id}'s and {share:.0%} of it "
                             f"within {a.id}'s face across, where the camera could not have seen it; their "
                             f"perceived faces {CONTRADICTION}")
            elif behind < MIN_BOX_DEPTH - REPAIRABLE and across.min() > REPAIRABLE:
                notes.append(f"{b.id}: its face lies {behind * 100:.1f} cm behind {a.id}'s, {across[0] * 100:.0f}x"
                             f"{across[1] * 100:.0f} cm of it within {a.id}'s face across, where {a.id}'s box (at "
                             f"least {MIN_BOX_DEPTH * 100:.0f} cm deep) would pass through it; their perceived "
                             f"faces {CONTRADICTION}")
    return notes


def _under_the_top(boxes: list[Box], shelf: Shelf) -> tuple[list[Box], list[str]]:
    """A box reaching above the shelf's top is cut down to fit, its bottom where it rests: the
    stack under it measured taller than the shelf, so some face in it is wrong, and the warning
    says so (a box pushed out of the top into the one under it is a world the planner cannot
    build). A box that would keep less than half its height is left, and reported."""
    out, notes = list(boxes), []
    for i, b in enumerate(out):
        a = _aabb(b)
        over = a[1, 2] - shelf.height
        if over <= 1e-6 or b.id.startswith("~") or b.size[2] - over < b.size[2] / 2:
            continue
        out[i] = _taller(b, -over)
        notes.append(f"{b.id}: its stack reaches {a[1, 2]:.3f} m, above the shelf's top ({shelf.height:.3f} m); "
                     f"cut {over * 100:.1f} cm shorter to fit: the perceived faces of its stack {CONTRADICTION}")
    return out, notes


def _push_apart(boxes: list[Box], snap: float, min_contact: float) -> tuple[list[Box], list[str]]:
    """Neighbours side by side at one height whose measured faces overlap sideways by at most
    `snap` (on their oriented shapes, `contact.face_sweep`), moved apart by half the overlap
    each; and what was moved. Placeholder depths that cross behind the faces move nothing."""
    out = list(boxes)
    notes: list[str] = []
    order = sorted(range(len(out)), key=lambda i: _aabb(out[i])[0, 0])
    for ii, i in enumerate(order):
        for j in order[ii + 1:]:
            a, c = _aabb(out[i]), _aabb(out[j])
            if _overlap(a, c, 0) <= 0 or _overlap(a, c, 2) < min_contact or _overlap(a, c, 1) <= 0:
                continue
            # only neighbours side by side (their centres apart more in x than z)
            dxc = abs((a[0, 0] + a[1, 0]) - (c[0, 0] + c[1, 0])) / 2
            dzc = abs((a[0, 2] + a[1, 2]) - (c[0, 2] + c[1, 2])) / 2
            if dzc > dxc:
                continue
            left, right = (i, j) if a[0, 0] + a[1, 0] <= c[0, 0] + c[1, 0] else (j, i)
            s = face_sweep(out[left], out[right], (1.0, 0.0, 0.0))
            if s is None or not s[0] < 0 < s[1]:
                continue
            why = ""
            if -s[0] > snap:
                if out[left].id.startswith("~") or out[right].id.startswith("~"):
                    continue    # unexplained matter's stand-ins ('~') are never pushed past snap
                # deeper: parted only where the two measured faces themselves overlap (not a
                # placeholder depth reaching a face behind it) and sideways is their shortest way
                # apart (else they rest on each other, or stand one behind the other); both
                # cannot be right, and it is said
                s = sweep(face_part(out[left]), face_part(out[right]), (1.0, 0.0, 0.0))
                if s is None or not s[0] < 0 < s[1] or -s[0] > _face_depth(out[left], out[right]) + 1e-6:
                    continue
                why = f"; their perceived faces {CONTRADICTION}"
            half = -s[0] / 2 + 1e-4
            out[left] = _moved(out[left], np.array([-half, 0, 0]))
            out[right] = _moved(out[right], np.array([half, 0, 0]))
            notes.append(f"{out[left].id}/{out[right].id}: pushed apart sideways by {-s[0] * 100:.1f} cm overlap{why}")
    return out, notes


def _support(b: Box, other: Box, bottom: float, snap: float) -> tuple[float | None, str]:
    """The upward move that rests `b` on `other` (None: `other` is not under it), on their
    oriented shapes (`contact.sweep`); and a note when a deep overlap is left alone.

    Touching, a gap or an overlap up to `snap`: rest on it. A deeper overlap with `other`
    lower: `b` was measured partly inside it and rests on it, but only when a measured face is
    in the overlap and lifting is the shortest way out (`_beside`: else `other` stands beside
    `b`); one between placeholder depths only (turned neighbours whose unseen backs cross) says
    nothing about where the faces are: not a support (the note says so; the caller then never
    drops `b` through it)."""
    s = sweep(b, other, UP)
    if s is None or s[0] >= 0:
        return None, ""
    if s[1] <= snap:
        return s[1], ""
    if min(c[2] for c in other.corners()) >= bottom - 1e-3:
        return None, ""
    f = face_sweep(b, other, UP)
    if f is not None and f[0] < 0 < f[1]:
        return (None, "") if _beside(b, other, bottom, snap) else (f[1], "")
    return None, f"{b.id}/{other.id}: overlap behind their measured faces only (depths unknown); not moved"


SIDEWAYS = (1.0, 0.0, 0.0)


def _beside(b: Box, other: Box, bottom: float, snap: float) -> float:
    """The move along x (signed; 0.0: none) that parts `b` from `other`, a lower box it overlaps
    deeper than `snap` in height with a measured face in the overlap, when that move is shorter
    than lifting `b` out of it: then `other` stands beside `b`, not under it.

    Why: a face measured a centimetre or two too wide or off-centre (the face error) reaches
    into the box beside it by that much sideways, over all the height the two share; read as
    resting on it, it was lifted 14-25 cm out of it, into the box above or off its own support
    (issue 31, `make_valid_jitter.py`: tuning shelves 31000, 31012, 31026 refused). A box
    measured partly inside the box it rests on overlaps it the other way round: by the face
    error in height, by much of its width sideways. The shorter way out is the one the face
    error explains."""
    s = sweep(b, other, UP)
    if s is None or s[0] >= 0 or s[1] <= snap or min(c[2] for c in box_corners(other)) >= bottom - 1e-3:
        return 0.0
    f = face_sweep(b, other, UP)
    x = face_sweep(b, other, SIDEWAYS)
    if f is None or not f[0] < 0 < f[1] or x is None or not x[0] < 0 < x[1]:
        return 0.0
    side = x[0] - 1e-4 if -x[0] < x[1] else x[1] + 1e-4
    return side if abs(side) < f[1] else 0.0


def _part_sideways(out: list[Box], i: int, placed: list[int], snap: float, half_width: float) -> list[str]:
    """Box `i` parted sideways from the lower boxes beside it that it was measured into
    (`_beside`), before it rests; and what was done. It moves away from them as far as the room
    on its other side allows (the shelf's side, the next placed box); what is left is cut off
    its width on their side (its face was measured wider than the gap it stands in: with
    neighbours on both sides, only cut). It is never cut below half its width."""
    b = out[i]
    bottom = _aabb(b)[0, 2]
    moves = {j: m for j in placed if (m := _beside(b, out[j], bottom, snap))}
    if not moves:
        return []
    names = "/".join(out[j].id for j in moves)
    left = max([m for m in moves.values() if m < 0], key=abs, default=0.0)
    right = max([m for m in moves.values() if m > 0], default=0.0)
    shift = 0.0
    if not (left and right):
        shift = math.copysign(min(abs(left + right), _room(out, i, placed, moves, left + right > 0, half_width)),
                              left + right)
    cut_left, cut_right = (right - shift if right else 0.0), (shift - left if left else 0.0)
    if cut_left + cut_right > b.size[0] / 2:
        return [f"{b.id}: measured {max(right, -left) * 100:.1f} cm into {names} beside it; "
                f"parting them would cut it below half its width: not moved"]
    out[i] = _narrower(_moved(b, np.array([shift, 0.0, 0.0])), cut_left, cut_right)
    reach, cut = max(right, -left), cut_left + cut_right
    if reach <= 1e-3:
        return []
    said = [f"moved {abs(shift) * 100:.1f} cm {'right' if shift > 0 else 'left'}"] if abs(shift) > 5e-4 else []
    said += [f"cut {cut * 100:.1f} cm narrower"] if cut > 5e-4 else []
    # as when side-by-side faces are pushed apart: past `snap` both faces cannot be right
    why = "; their perceived faces " + CONTRADICTION if reach > snap else ""
    return [f"{b.id}: {' and '.join(said)} out of {names} beside it (not resting on it: its face "
            f"reached {reach * 100:.1f} cm into {names} sideways){why}"]


def _room(out: list[Box], i: int, placed: list[int], moves: dict[int, float], right: bool,
          half_width: float) -> float:
    """How far box `i` moves sideways (right, else left) before it meets the shelf's side or a
    placed box it is apart from now (other than those in `moves`)."""
    a = _aabb(out[i])
    room = half_width - a[1, 0] if right else a[0, 0] + half_width
    d = (1.0, 0.0, 0.0) if right else (-1.0, 0.0, 0.0)
    for j in placed:
        s = None if j in moves else face_sweep(out[i], out[j], d)
        if s is not None and s[0] >= 0:
            room = min(room, s[0])
    return max(room - 1e-4, 0.0)


def _narrower(b: Box, cut_left: float, cut_right: float) -> Box:
    """The box cut `cut_left` narrower on its left (-x) side and `cut_right` on its right, along
    its own x axis (what the cut leaves stays where it was)."""
    if cut_left + cut_right <= 0:
        return b
    ex = np.asarray(quat_to_matrix(b.orientation))[:, 0]
    ex = ex if ex[0] >= 0 else -ex
    pos = np.asarray(b.position) + ex * (cut_left - cut_right) / 2
    return replace(b, size=(float(b.size[0] - cut_left - cut_right), b.size[1], b.size[2]),
                   position=tuple(float(p) for p in pos))


def _rest_on_supports(boxes: list[Box], snap: float, min_contact: float,
                      height: float = np.inf, half_width: float = np.inf) -> tuple[list[Box], list[str]]:
    """Every box, lowest first, parted sideways from lower boxes beside it (`_part_sideways`),
    then moved up or down onto the floor or the highest box under it; and what was moved (more
    than 1 mm). A support whose top edge was hidden grows up to the
    box above only where growing overlaps no other box and that box fits under the shelf's
    top (`height`); otherwise the box above drops, as onto any support (`_may_grow`)."""
    out = list(boxes)
    notes: list[str] = []
    order = sorted(range(len(out)), key=lambda i: _aabb(out[i])[0, 2])
    placed: list[int] = []
    for i in order:
        notes += _part_sideways(out, i, placed, snap, half_width)
        a = _aabb(out[i])
        bottom = a[0, 2]
        delta, under, held, k = -bottom, "the floor", False, None
        for j in placed:
            c = _aabb(out[j])
            if _overlap(a, c, 0) < min_contact or _overlap(a, c, 1) <= 0:
                continue
            up, note = _support(out[i], out[j], bottom, snap)
            if note:
                notes.append(note)
                held = True
            if up is not None and up > delta:
                delta, under, k = up, out[j].id, j
        if held and delta < -snap:
            delta = 0.0         # its unseen back may rest on that box: the measured face stays
        if delta < -snap and k is not None and -delta <= MAX_HIDDEN_TOP and _top_hidden(out[k]):
            # the support's top edge was hidden behind a box in front: it is taller than it was seen
            why = _may_grow(out, k, i, -delta, height)
            if why:
                notes.append(f"{out[k].id}: top edge hidden, but growing it {-delta * 100:.1f} cm up to "
                             f"{out[i].id} {why}: {out[i].id} drops instead")
            else:
                out[k] = _taller(out[k], -delta)
                notes.append(f"{out[k].id}: top edge hidden, grown {-delta * 100:.1f} cm up to {out[i].id} above it")
                delta = 0.0
        if abs(delta) > 1e-3:
            # as sideways (`_part_sideways`): a move past `snap` is no measurement error, so the
            # faces it names cannot all be right, and it is said (planning does not call a plan
            # touching them safe)
            why = f"; their perceived faces {CONTRADICTION}" if abs(delta) > snap else ""
            if delta > 0:
                notes.append(f"{out[i].id}: pushed up {delta * 100:.1f} cm out of {under}{why}")
            elif -delta <= snap:
                notes.append(f"{out[i].id}: lowered {-delta * 100:.1f} cm onto {under} (gap closed)")
            else:
                notes.append(f"{out[i].id}: hung {-delta * 100:.1f} cm in the air; dropped onto {under}{why}")
        if delta != 0:
            out[i] = _moved(out[i], np.array([0.0, 0.0, delta]))
        placed.append(i)
    return out, notes


MAX_HIDDEN_TOP = 0.12    # a support whose top edge was hidden grows at most this much to carry a box


def _top_hidden(b: Box) -> bool:
    return bool((b.extra.get("perceived") or {}).get("top_hidden"))


def _may_grow(boxes: list[Box], k: int, i: int, dz: float, height: float) -> str:
    """Why support `k` may not grow `dz` up to box `i` above it ('' when it may): the grown box
    would overlap another box deeper than it did (that box was placed on it, or beside it), or
    box `i` left where it was seen reaches above the shelf's top."""
    if _aabb(boxes[i])[1, 2] > height + 1e-6:
        return f"would leave {boxes[i].id} above the shelf's top"
    grown = _taller(boxes[k], dz)
    for j, b in enumerate(boxes):
        if j not in (k, i) and _face_depth(grown, b) > _face_depth(boxes[k], b) + 1e-3:
            return f"would overlap {b.id}"
    return ""


def _taller(b: Box, dz: float) -> Box:
    """The box `dz` taller along its own z axis, its bottom where it was."""
    ez = np.asarray(quat_to_matrix(b.orientation))[:, 2]
    pos = np.asarray(b.position) + ez * dz / 2
    return replace(b, size=(b.size[0], b.size[1], float(b.size[2] + dz)), position=tuple(float(p) for p in pos))


def _clamp(b: Box, shelf: Shelf, notes: list[str]) -> Box:
    a = _aabb(b)
    half = shelf.width / 2
    dx = 0.0
    if a[1, 0] - a[0, 0] > shelf.width:
        dx = -(a[0, 0] + a[1, 0]) / 2
    elif a[0, 0] < -half:
        dx = -half - a[0, 0]
    elif a[1, 0] > half:
        dx = half - a[1, 0]
    if abs(dx) > 1e-6:
        b = _moved(b, np.array([dx, 0.0, 0.0]))
        if abs(dx) > 1e-3:
            notes.append(f"{b.id}: moved {abs(dx) * 100:.1f} cm {'right' if dx > 0 else 'left'} into the shelf")
    a = _aabb(b)
    if a[1, 1] > shelf.depth + 1e-6:
        excess = a[1, 1] - shelf.depth
        if not b.depth_known and b.size[1] - excess >= 0.01:
            b = b.with_depth(b.size[1] - excess)
        else:
            b = _moved(b, np.array([0.0, -excess, 0.0]))
            if excess > 1e-3:
                notes.append(f"{b.id}: moved {excess * 100:.1f} cm forward off the back wall")
    a = _aabb(b)
    if a[0, 2] < 0:
        b = _moved(b, np.array([0.0, 0.0, -a[0, 2]]))
    return b


# a face may stick out of the shelf by this much (boxes overhang the front, masks bleed a little)
FRONT_MARGIN = 0.10
# and stand this far in front of the shelf's front plane before it cannot be on the shelf
MAX_PROTRUSION = 0.50


def not_a_front(f: FrontFace, shelf: Shelf) -> str:
    """Why a measured face cannot be a box on this shelf ('' when it can).

    A mask of the floor, a wall, a neighbouring bay or (in a photo with a flat stand-in depth) a
    region near the horizon back-projects to faces metres wide or far away; kept, `make_valid`
    would stack every other box on top of them.
    """
    x, y, z = (float(v) for v in f.center)
    m = FRONT_MARGIN
    if not all(math.isfinite(v) for v in (x, y, z, f.width, f.height)):
        return "not finite"
    if f.width < 0.02 or f.height < 0.02:
        return "smaller than 2 cm"
    if f.width > shelf.width + m or f.height > shelf.height + m:
        return f"larger than the {shelf.width:.2f}x{shelf.height:.2f} m shelf"
    if y > shelf.depth + 0.05:
        return "behind the shelf's back wall"
    if y < -MAX_PROTRUSION:
        return f"more than {MAX_PROTRUSION:.2f} m in front of the shelf"
    if abs(x) - f.width / 2 > shelf.width / 2 + m or z - f.height / 2 > shelf.height + m \
            or z + f.height / 2 < -m:
        return "outside the shelf"
    return ""


# a box front face, even partly hidden, fills its min-area rectangle this well (rendered tuning
# sets 700-719, 800-839: every matched mask >= 0.68) ...
MIN_RECT_FILL = 0.5
# ... and is no strip thinner than this and this many times as long, unless an image border
# (top, left, right) cuts it (matched masks there: short side >= 15 cm, long / short <= 3.4)
STRIP_MAX_SIDE = 0.10
STRIP_MIN_ASPECT = 5.0


def not_a_face(f: FrontFace, mask: np.ndarray) -> str:
    """Why a mask on the shelf is still no box front ('' when it can be): a ragged region filling
    its rectangle less than `MIN_RECT_FILL` (the dark edge of a machine base), or a long thin
    strip not cut by the top/left/right border (pallet boards seen from above, shelf lips)."""
    from shelfpick.perception.repairs.merged import rect_fill

    if int(np.count_nonzero(mask)) < 3:
        return ""
    fill = rect_fill(mask)
    if fill < MIN_RECT_FILL:
        return f"fills only {fill:.2f} of its rectangle"
    short, long_ = sorted((f.width, f.height))
    if short < STRIP_MAX_SIDE and long_ >= STRIP_MIN_ASPECT * short and \
            not border_sides(mask, sides=("top", "left", "right")):
        return f"a {long_ * 100:.0f}x{short * 100:.0f} cm strip"
    return ""


# --------------------------------------------------------------------------
MIN_PART_SIDE = 0.06     # a part cut off a merged mask is a box front at least this wide and high


def split_merged(masks: list[np.ndarray], faces: list[FrontFace | None] | None, depth: np.ndarray,
                 camera: Camera, shelf: Shelf, min_px: int) -> tuple[list[np.ndarray], list[FrontFace | None], list[str]]:
    """(masks, faces, notes): a mask that is two boxes cut by geometry (issue 31): at a depth step
    running through it (one box behind the other), or, when it fills its rectangle too badly to be
    one front, at the row or column that leaves well-filled parts (two boxes of one colour side by
    side). A mask is cut only when every part measures as a box front; its faces are re-measured."""
    from shelfpick.perception.faces import face_normal
    from shelfpick.perception.repairs.merged import depth_step_parts, off_plane_trimmed, rect_fill, rectangle_parts, trimmed

    out_m: list[np.ndarray] = []
    out_f: list[FrontFace | None] = []
    notes: list[str] = []
    for i, m in enumerate(masks):
        m = np.asarray(m, bool)
        f = faces[i] if faces is not None else measure_front(m, depth, camera)
        if f is not None:
            t = off_plane_trimmed(m, f.center, face_normal(f.yaw, f.tilt), depth, camera)
            g = measure_front(t, depth, camera) if t is not m and t.sum() >= 0.7 * m.sum() else None
            if g is not None:
                m, f = t, g
        parts, how = depth_step_parts(m, depth, min_px), "cut at a depth step into"
        if len(parts) < 2 and f is not None and not not_a_front(f, shelf) and not_a_face(f, m).startswith("fills"):
            t = trimmed(m)
            base = t if t.sum() >= 0.6 * m.sum() else m
            if rect_fill(base) >= MIN_RECT_FILL:
                parts, how = [base], "thin strands trimmed,"
            else:
                parts, how = rectangle_parts(base, min_px), "cut at the outline's corners into"
        if len(parts) >= 2 or parts[0] is not m:
            pf = [measure_front(p, depth, camera) for p in parts]
            if all(q is not None and not (not_a_front(q, shelf) or not_a_face(q, p)) and min(q.width, q.height)
                   >= MIN_PART_SIDE for q, p in zip(pf, parts)):
                notes.append(f"mask {i + 1} is {len(parts)} front{'s' if len(parts) > 1 else ''}: {how} "
                             + " and ".join(q.size_cm for q in pf if q is not None))
                out_m.extend(parts)
                out_f.extend(pf)
                continue
        out_m.append(m)
        out_f.append(f)
    return out_m, out_f, notes


def boxes_from_masks(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, shelf: Shelf,
                     placeholder: float = 0.25, faces: list[FrontFace | None] | None = None,
                     split_min_px: int | None = None,
                     ) -> tuple[list[Box], list[np.ndarray], list[FrontFace], list[str]]:
    """Measure every mask; boxes get ids b0.. ordered bottom-up then left to right.

    Returns boxes, the masks in the same order (mask_label = index + 1), the faces
    and warnings about masks that could not be measured. `faces`: the masks' faces when
    they were measured already (`measure_front` on the same depth), None to measure here.
    `split_min_px`: cut masks that are two boxes (`split_merged`, parts of at least this many
    pixels; real depth only); None: never.
    """
    warnings: list[str] = []
    if split_min_px is not None:
        masks, faces, cut = split_merged(masks, faces, depth, camera, shelf, split_min_px)
        warnings.extend(cut)
    measured = faces
    faces: list[tuple[FrontFace, np.ndarray]] = []  # type: ignore[no-redef]
    for i, m in enumerate(masks):
        f = measured[i] if measured is not None else measure_front(m, depth, camera)
        if f is None:
            warnings.append(f"mask {i + 1}: too little valid depth to measure; dropped")
            continue
        why = not_a_front(f, shelf) or not_a_face(f, m)
        if not why and f.center[1] + placeholder < 0.01:
            # its box (placeholder depth) would lie wholly in front of the shelf: a scene the
            # format refuses to load (a flat depth 0.5 m from the camera wrote one)
            why = f"its box, {placeholder:.2f} m deep, would not reach into the shelf"
        if why:
            warnings.append(f"mask {i + 1}: face at x={f.center[0]:.2f} y={f.center[1]:.2f} z={f.center[2]:.2f} m, "
                            f"{f.width:.3f}x{f.height:.3f} m is not a box front ({why}); dropped")
            continue
        faces.append((f, m))
    faces.sort(key=lambda fm: (round((fm[0].center[2] - fm[0].height / 2) / 0.05), fm[0].center[0]))
    boxes = [box_from_face(f, f"b{k}", k + 1, shelf, placeholder) for k, (f, _) in enumerate(faces)]
    if split_min_px is not None:       # real depth: where a box in front hides a face's top edge
        from shelfpick.perception.repairs.merged import top_edge_hidden

        boxes = [replace(b, extra={**b.extra, "perceived": {**b.extra["perceived"], "top_hidden": True}})
                 if top_edge_hidden(m, depth) else b for b, (_, m) in zip(boxes, faces)]
    return boxes, [m for _, m in faces], [f for f, _ in faces], warnings


def planar_depth(camera: Camera, distance: float) -> np.ndarray:
    """A depth image of a flat front at `distance` m in front of the camera (no depth sensor)."""
    if not (distance > 0 and math.isfinite(distance)):
        raise PerceptionError(f"front distance must be a positive number of metres, got {distance!r}")
    return np.full((camera.height, camera.width), float(distance), np.float32)


def distance_from_box_size(masks: list[np.ndarray], camera: Camera, box_size: tuple[float, float]) -> float:
    """The distance at which the median mask's pixel size matches a known front-face size (W, H in m)."""
    if len(box_size) != 2 or min(box_size) <= 0:
        raise PerceptionError(f"--box-size needs two positive sizes in metres (W H), got {box_size!r}")
    long_m, short_m = max(box_size), min(box_size)
    f = math.sqrt(camera.fx * camera.fy)
    est = []
    for m in masks:
        pts = cv2.findNonZero(m.astype(np.uint8))
        if pts is None or len(pts) < 20:
            continue
        (_, _), (w, h), _ = cv2.minAreaRect(pts)
        lp, sp = max(w, h) + 1, min(w, h) + 1
        est.append(0.5 * (f * long_m / lp + f * short_m / sp))
    if not est:
        raise PerceptionError("cannot derive a distance from --box-size: no box was found in the image")
    return float(np.median(est))


def default_front_distance(camera: Camera) -> float:
    """Distance along the optical axis from the camera to the shelf's front plane (y = 0)."""
    rot = np.asarray(quat_to_matrix(camera.orientation))
    fwd = rot[:, 2]
    if fwd[1] <= 1e-3 or camera.position[1] >= 0:
        return 1.0
    return float(-camera.position[1] / fwd[1])   # camera z of the plane along the optical axis
