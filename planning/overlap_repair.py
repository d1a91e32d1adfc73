"""Pushing apart the boxes of a perceived shelf that overlap a little, before it settles.

Perceived faces are off by about a centimetre, so two boxes built from them may
overlap by a few millimetres, and a box may reach into a wall. Overlaps up to
`repair_tolerance` are pushed apart (a stacked pair lifts the upper box, a
side-by-side pair moves each box by half, a box in a wall is pushed out);
deeper ones raise `SceneError` naming both. Overlaps under `repair_min_overlap`
are left to the contact solver (docs/physics.md, "Repair and refusal"). A box resting on a
strip of another's top edge narrower than `edge_perch` is first moved off that edge
(`clear_perches`).
"""
from __future__ import annotations

from shelfpick.perception.errors import SceneError
from shelfpick.planning.bullet_clients import Client
from shelfpick.planning.geometry3 import norm
from shelfpick.planning.physics import PhysicsConfig

# (depth, box, other box or None for a shelf part, normal pointing out of the other, other body)
Penetration = tuple[float, str, "str | None", tuple, int]


class OverlapError(SceneError):
    """An overlap past repair, with the boxes it names (`boxes`): the planner may set those
    perceived faces aside (planning/set_aside.py) instead of refusing the whole shelf."""

    def __init__(self, message: str, boxes: tuple[str, ...] = (), detail: str = "") -> None:
        super().__init__(message)
        self.boxes = tuple(boxes)
        self.detail = detail or message      # the overlap itself, without what was tried around it

    def __reduce__(self):  # crosses process boundaries (worker pools) with its boxes
        return (type(self), (str(self), self.boxes, self.detail))


def _overlaps(a, b) -> bool:
    return all(a[0][k] < b[1][k] and b[0][k] < a[1][k] for k in range(3))


def penetrations(p: Client, ids: tuple[str, ...], body: dict[str, int], static: dict[int, str],
                 config: PhysicsConfig) -> list[Penetration]:
    """Every overlap deeper than `repair_min_overlap`: a settled Bullet stack rests ~1 mm deep
    in its contacts, and "repairing" that on every reload of a settled scene would only lift
    boxes that then drop back."""
    eps = -config.repair_min_overlap
    out: list[Penetration] = []
    aabb = {bid: p.getAABB(body[bid]) for bid in ids}
    for i, a in enumerate(ids):
        ba = body[a]
        for sbody, sname in static.items():
            if sname == "ground" or not _overlaps(aabb[a], p.getAABB(sbody)):
                continue
            for c in p.getClosestPoints(ba, sbody, 0.0):
                if c[8] < eps:
                    out.append((-c[8], a, None, tuple(c[7]), sbody))
        for b in ids[i + 1:]:
            if not _overlaps(aabb[a], aabb[b]):
                continue
            cs = p.getClosestPoints(ba, body[b], 0.0)
            if cs:
                c = min(cs, key=lambda c: c[8])
                if c[8] < eps:
                    out.append((-c[8], a, b, tuple(c[7]), body[b]))
    return out


class _Shifts:
    """Moves boxes along a normal and remembers, per box, the total offset and from what."""

    def __init__(self, p: Client, body: dict[str, int], push: float) -> None:
        self.p, self.body, self.push = p, body, push
        self.moved: dict[str, list] = {}

    def shift(self, bid: str, n: tuple, d: float, other: str) -> None:
        pos, orn = self.p.getBasePositionAndOrientation(self.body[bid])
        step = tuple(n[k] * (d + self.push) for k in range(3))
        self.p.resetBasePositionAndOrientation(self.body[bid], [pos[k] + step[k] for k in range(3)], orn)
        off, others = self.moved.setdefault(bid, [(0.0, 0.0, 0.0), []])
        self.moved[bid][0] = tuple(off[k] + step[k] for k in range(3))
        name = repr(other) if other != "the shelf" else other
        if name not in others:
            others.append(name)

    def apart(self, pen: Penetration) -> None:
        """Undo one overlap; the normal points from the other body to the box."""
        depth, a, b, n, _ = pen
        if b is None:
            self.shift(a, n, depth, "the shelf")
        elif abs(n[2]) > 0.5:   # stacked: lift the upper box only
            za = self.p.getBasePositionAndOrientation(self.body[a])[0][2]
            zb = self.p.getBasePositionAndOrientation(self.body[b])[0][2]
            if za >= zb:
                self.shift(a, n, depth, b)
            else:
                self.shift(b, tuple(-x for x in n), depth, a)
        else:
            self.shift(a, n, depth / 2, b)
            self.shift(b, tuple(-x for x in n), depth / 2, a)

    def messages(self, ids: tuple[str, ...]) -> list[str]:
        msgs = []
        for bid in ids:
            if bid in self.moved:
                off, others = self.moved[bid]
                if norm(off) > 1e-4:
                    msgs.append(f"box {bid!r} moved {norm(off):.3f} m by ({off[0]:+.3f}, {off[1]:+.3f}, "
                                f"{off[2]:+.3f}) to undo its overlap with {', '.join(others)}")
        return msgs


def _level(p: Client, body: int, tol: float = 0.02) -> bool:
    """Whether a box stands square (its axes within ~1 deg of the world's): its AABB is its shape."""
    q = p.getBasePositionAndOrientation(body)[1]
    m = p.getMatrixFromQuaternion(q)
    return all(max(abs(m[3 * i + j]) for j in range(3)) > 1 - tol for i in range(3))


def _perch(a: tuple, b: tuple, edge: float) -> tuple[int, float] | None:
    """(axis, overlap) when box `a` (AABB) rests on the top of `b` by a strip narrower than `edge`
    along one horizontal axis, its centre beyond b's side; None otherwise."""
    if abs(a[0][2] - b[1][2]) > edge:
        return None
    ov = [min(a[1][k], b[1][k]) - max(a[0][k], b[0][k]) for k in range(2)]
    for k in range(2):
        centre = (a[0][k] + a[1][k]) / 2
        if 0 < ov[k] <= edge and ov[1 - k] > edge and not b[0][k] <= centre <= b[1][k]:
            return k, ov[k]
    return None


def clear_perches(p: Client, ids: tuple[str, ...], body: dict[str, int], config: PhysicsConfig) -> list[str]:
    """Move a box that rests on a strip of another's top edge narrower than `edge_perch` sideways
    off that edge (what moved, one line a box). A carton's edge is rounded and crushes over a few
    mm, so such a strip carries nothing on a real shelf; it comes from face error, and in Bullet
    it made a lifted neighbour throw the box off the shelf (1.1 m, docs/physics.md)."""
    edge = config.edge_perch
    if edge <= 0:
        return []
    shifts = _Shifts(p, body, config.repair_push)
    level = {bid: _level(p, body[bid]) for bid in ids}
    for a in ids:
        for b in ids:
            if a == b or not (level[a] and level[b]):
                continue
            found = _perch(p.getAABB(body[a]), p.getAABB(body[b]), edge)
            if found is None:
                continue
            k, ov = found
            ca = p.getBasePositionAndOrientation(body[a])[0][k]
            cb = p.getBasePositionAndOrientation(body[b])[0][k]
            n = tuple((1.0 if ca > cb else -1.0) if i == k else 0.0 for i in range(3))
            shifts.shift(a, n, ov, b)
    return [m.replace("to undo its overlap with", "off the edge of") for m in shifts.messages(ids)]


def repair_overlaps(p: Client, ids: tuple[str, ...], body: dict[str, int], static: dict[int, str],
                    config: PhysicsConfig) -> list[str]:
    """Push apart overlaps up to `repair_tolerance` (what moved, one line a box); a deeper one,
    or one that does not go away in `repair_rounds`, raises SceneError."""
    tol = config.repair_tolerance
    pens = penetrations(p, ids, body, static, config)
    for depth, a, b, _, sbody in sorted(pens, key=lambda x: -x[0]):
        if depth > tol:
            other = f"box {b!r}" if b else f"the shelf's {static[sbody]}"
            raise OverlapError(f"box {a!r} and {other} overlap by {depth:.3f} m "
                               f"(more than the {tol:.3f} m that can be repaired)", (a, b) if b else (a,))
    shifts = _Shifts(p, body, config.repair_push)
    for _ in range(config.repair_rounds):
        if not pens:
            break
        for pen in pens:
            shifts.apart(pen)
        pens = penetrations(p, ids, body, static, config)
    if pens:
        worst = max(pens, key=lambda x: x[0])
        raise OverlapError(f"box {worst[1]!r} overlaps {worst[2] or 'the shelf'} and the overlap "
                           f"cannot be repaired", (worst[1], worst[2]) if worst[2] else (worst[1],))
    return shifts.messages(ids)
