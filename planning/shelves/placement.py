"""Placing boxes geometrically: the growing arrangement (a height map over the shelf floor), the
oriented-box overlap test and the support test every placement passes.

A box lands on the highest surface under its footprint; it is refused where it
would overlap a placed box (exact oriented-box test, GAP kept between boxes),
stick out of the shelf, or put the centre of mass of a stack outside what holds
it. Names with a leading underscore are shared inside planning.shelves only.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from shelfpick.perception.scene import Box, Shelf, quat_to_matrix

PROUD_RANGE = (0.01, 0.06)           # m a proud box's front face sticks out of the shelf front

SHELF = Shelf()                     # 100 x 30 x 160 cm, the method's (perception.scene)
STANDING_LONG = (0.17, 0.17, 0.50)

DENSE_FROM = 16                      # unstructured scenes above this size: turned, shifted columns
FRONT_MIN, FRONT_MAX = -0.05, 0.05   # y of the front face (boxes stick out up to 5 cm)
GAP = 0.004                          # clearance kept between placed boxes, m
CELL = 0.005                         # height-map resolution, m
Y_MIN_GRID = -0.12                   # the grid covers the part of boxes sticking out in front


@dataclass
class _Placed:
    size: tuple[float, float, float]
    position: tuple[float, float, float]
    orientation: tuple[float, float, float, float]
    leaning: bool = False
    sole: int | None = None          # index of the one box it rests on (None: floor, or shared support)
    hull: np.ndarray | None = None   # its support polygon (convex hull equations, xy)

    def box(self, bid: str) -> Box:
        return Box(bid, self.size, self.position, self.orientation)


def _axis_quat(axis: Sequence[float], angle: float) -> tuple[float, float, float, float]:
    s = math.sin(angle / 2)
    return (math.cos(angle / 2), axis[0] * s, axis[1] * s, axis[2] * s)


def obb_overlap(a: _Placed, b: _Placed, margin: float = 0.0) -> bool:
    """Separating-axis test for two oriented boxes, each grown by `margin` on every side."""
    ra = np.array(quat_to_matrix(a.orientation))
    rb = np.array(quat_to_matrix(b.orientation))
    ha = np.array(a.size) / 2 + margin
    hb = np.array(b.size) / 2 + margin
    t = np.array(b.position) - np.array(a.position)
    axes = [ra[:, i] for i in range(3)] + [rb[:, i] for i in range(3)]
    for i in range(3):
        for j in range(3):
            c = np.cross(ra[:, i], rb[:, j])
            n = np.linalg.norm(c)
            if n > 1e-9:
                axes.append(c / n)
    for ax in axes:
        pa = sum(ha[k] * abs(ax @ ra[:, k]) for k in range(3))
        pb = sum(hb[k] * abs(ax @ rb[:, k]) for k in range(3))
        if abs(t @ ax) > pa + pb:
            return False
    return True


class _Layout:
    """The growing arrangement: placed boxes plus a height map of their tops."""

    def __init__(self, shelf: Shelf):
        self.shelf = shelf
        self.xs = np.arange(-shelf.width / 2 + CELL / 2, shelf.width / 2, CELL)
        self.ys = np.arange(Y_MIN_GRID + CELL / 2, shelf.depth, CELL)
        self.gx, self.gy = np.meshgrid(self.xs, self.ys, indexing="ij")
        self.height = np.zeros(self.gx.shape)
        # the floor supports only inside the shelf (y >= 0); in front of it there is nothing
        self.support = self.gy >= 0.0
        self.owner = np.full(self.gx.shape, -1, dtype=int)   # which box's top is the surface here
        self.placed: list[_Placed] = []
        self.load: list[list[int]] = []                    # boxes resting (through sole supports) on each

    def footprint(self, cx: float, cy: float, sx: float, sy: float, yaw: float) -> np.ndarray:
        c, s = math.cos(yaw), math.sin(yaw)
        r = math.hypot(sx, sy) / 2
        i0, i1 = np.searchsorted(self.xs, [cx - r, cx + r])
        j0, j1 = np.searchsorted(self.ys, [cy - r, cy + r])
        out = np.zeros(self.gx.shape, dtype=bool)
        dx, dy = self.gx[i0:i1, j0:j1] - cx, self.gy[i0:i1, j0:j1] - cy
        u = c * dx + s * dy
        v = -s * dx + c * dy
        out[i0:i1, j0:j1] = (np.abs(u) <= sx / 2) & (np.abs(v) <= sy / 2)
        return out

    def fits_shelf(self, p: _Placed) -> bool:
        cs = np.array(p.box("_").corners())
        s = self.shelf
        return (cs[:, 0].min() >= -s.width / 2 + GAP and cs[:, 0].max() <= s.width / 2 - GAP
                and cs[:, 1].max() <= s.depth - GAP and cs[:, 1].min() >= Y_MIN_GRID
                and cs[:, 2].min() >= -1e-9 and cs[:, 2].max() <= s.height - GAP)

    def collides(self, p: _Placed) -> bool:
        # neighbours keep GAP between them; the quick distance check skips far boxes
        for q in self.placed:
            d = np.linalg.norm(np.array(p.position) - np.array(q.position))
            if d > (np.linalg.norm(p.size) + np.linalg.norm(q.size)) / 2 + 2 * GAP:
                continue
            if obb_overlap(p, q, GAP / 2 - 1e-6):
                return True
        return False

    def upright(self, size: tuple[float, float, float], cx: float, cy: float, yaw: float,
                min_support: float) -> _Placed | None:
        """An upright box (turned about z only) dropped at (cx, cy), or None if it cannot rest."""
        mask = self.footprint(cx, cy, size[0], size[1], yaw)
        if not mask.any():
            return None
        base = float(self.height[mask].max())
        sup = mask & self.support & (self.height >= base - 0.004)
        if sup.sum() < 4 or sup.sum() < min_support * mask.sum():
            return None
        hull = _hull(self.gx[sup], self.gy[sup])
        if hull is None or not _inside(hull, cx, cy, inset=0.02):
            return None
        owners = np.unique(self.owner[sup])
        sole = int(owners[0]) if len(owners) == 1 and owners[0] >= 0 else None
        p = _Placed(size, (cx, cy, base + size[2] / 2 + GAP), (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2)),
                    sole=sole, hull=hull)
        if not self.fits_shelf(p) or self.collides(p) or not self.carries(p):
            return None
        return p

    def carries(self, p: _Placed) -> bool:
        """Does every box below p (down a chain of sole supports) keep the load's centre of mass
        inside its own support polygon? (A box resting on two supports shares the load: not followed.)"""
        vol = p.size[0] * p.size[1] * p.size[2]
        s = p.sole
        while s is not None:
            q = self.placed[s]
            members = [q] + [self.placed[i] for i in self.load[s]]
            vols = [m.size[0] * m.size[1] * m.size[2] for m in members] + [vol]
            xs = [m.position[0] for m in members] + [p.position[0]]
            ys = [m.position[1] for m in members] + [p.position[1]]
            tot = sum(vols)
            cx = sum(v * x for v, x in zip(vols, xs)) / tot
            cy = sum(v * y for v, y in zip(vols, ys)) / tot
            if q.hull is None or not _inside(q.hull, cx, cy, inset=0.015):
                return False
            s = q.sole
        return True

    def add(self, p: _Placed) -> None:
        idx = len(self.placed)
        self.placed.append(p)
        self.load.append([])
        s = p.sole
        while s is not None:
            self.load[s].append(idx)
            s = self.placed[s].sole
        cs = np.array(p.box("_").corners())
        if p.leaning:
            # nothing may stand on a leaning box: raise its whole bounding rectangle, no support
            mask = ((self.gx >= cs[:, 0].min() - GAP) & (self.gx <= cs[:, 0].max() + GAP)
                    & (self.gy >= cs[:, 1].min() - GAP) & (self.gy <= cs[:, 1].max() + GAP))
            self.height[mask] = np.maximum(self.height[mask], cs[:, 2].max())
            self.support[mask] = False
            return
        yaw = 2 * math.atan2(p.orientation[3], p.orientation[0])
        mask = self.footprint(p.position[0], p.position[1], p.size[0], p.size[1], yaw)
        top = float(cs[:, 2].max())
        self.height[mask] = top
        self.support[mask] = True
        self.owner[mask] = idx


def _hull(px: np.ndarray, py: np.ndarray) -> np.ndarray | None:
    """Convex hull equations (normal . p + offset <= 0 inside) of support points; None if degenerate."""
    from scipy.spatial import ConvexHull, QhullError

    pts = np.column_stack([px, py])
    if len(pts) < 3:
        return None
    try:
        return ConvexHull(pts).equations
    except QhullError:
        return None


def _inside(hull: np.ndarray, cx: float, cy: float, inset: float) -> bool:
    """Is (cx, cy) at least `inset` inside the hull?"""
    d = hull[:, :2] @ np.array([cx, cy]) + hull[:, 2]
    return bool(np.all(d <= -inset))


def _extent(t: Sequence[float], yaw: float) -> tuple[float, float]:
    """Axis-aligned x and y extent of an upright box turned by yaw."""
    c, s = abs(math.cos(yaw)), abs(math.sin(yaw))
    return t[0] * c + t[1] * s, t[1] * c + t[0] * s


def _room(t: Sequence[float], top: float, cap: float) -> int:
    """How many boxes of type t still stack on a column whose top is at `top` under `cap`."""
    return max(0, int((cap - top + 1e-9) // (t[2] + GAP)))


def _cap(n: int) -> float:
    """Highest top a box may reach: small scenes stay low, large ones use the shelf's height."""
    return 1.3 if n <= 16 else SHELF.height - 0.05
