"""Known box types: join pieces of one face, split one mask that covers two boxes.

A warehouse usually stocks a few box types (the method's: 23x31x25, 20x20x20
and 50x17x17 cm), so a front face is one of a few rectangles. Two masks fail
that test in typical ways:
- a piece cut off a face (a label or tape at its border, one side of a tape
  band) is too small to be a face; joined with the neighbour on its plane the
  union is a known face;
- two flush boxes of one colour (stacked, or side by side) with a faint seam
  merge into one mask whose size is no type face, but which splits at one line
  into two type faces; the seam shows as a line of colour edges (and/or a small
  depth step) right there.
Both rules only act when the catalogue explains the result, within `tol`, so
a capture of other boxes (real data) is left as it is; the catalogue is a
parameter (`Catalogue(types=...)`), the reference types are the default.
perception/scene.py holds no type table the pipeline can use, so it lives here.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from perception.masks import border_pixels, border_sides
from perception.scene import BOX_TYPES, Camera

# the method's box types (w, d, h in metres): perception.scene's table
REFERENCE_TYPES: tuple[tuple[float, float, float], ...] = tuple(BOX_TYPES.values())


@dataclass(frozen=True)
class Catalogue:
    """Box types whose faces a front face may be; `tol` (m) is how close both sides must be."""

    types: tuple[tuple[float, float, float], ...] = REFERENCE_TYPES
    tol: float = 0.02
    join_tol: float = 0.025          # m: a joined union may be this far off a type face
    min_evidence: float = 5.0        # colour line/step along the split, in robust noise units ...
    depth_step: float = 0.004        # ... or a depth step (m) along the line counts as a seam
    min_share: float = 0.25         # used only when this share of the faces already are type faces
    max_join_gap_px: int = 12        # pieces this close (px) are neighbours (at REF_DEPTH, see `scaled`)
    l_margin_px: int = 10            # an L-cut leaves at least this many rows/columns on each side
    join_fill: float = 0.85          # a joined union fills its min-area rectangle this well ...
    join_fill_loose: float = 0.75    # ... or this well when it is a type face within `tol`
    plane_tol: float = 0.012         # m: a joined piece lies this close to its neighbour's plane
    row_margin: float = 0.05         # m: a mask this far off every type face may be a row of 3+
    weak_evidence: float = 0.5       # seam score enough to split such a mask into exactly two type faces
    max_depth: float | None = None   # m: a face whose box is deeper than this cannot face the front
    faces: tuple[tuple[float, float], ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        fs = set()
        for t in self.types:
            for i, j in itertools.permutations(range(3), 2):
                d = float(t[3 - i - j])
                if self.max_depth is not None and d > self.max_depth + 1e-9:
                    continue
                fs.add((round(float(t[i]), 4), round(float(t[j]), 4)))
        object.__setattr__(self, "faces", tuple(sorted(fs)))

    def within(self, depth: float | None, overhang: float = 0.05) -> "Catalogue":
        """Only the faces a box can show in a shelf this deep (its third side fits, sticking out
        of the front by up to `overhang`, as the planner's shelves allow): in a 30 cm shelf the
        50x17x17 box never shows its 17x17 end, so a third of its 17x50 face cut off by tape is
        no type face; the 23x31x25 box may show 23x25 (31 cm deep, 1 cm out)."""
        from dataclasses import replace

        return self if depth is None else replace(self, max_depth=float(depth) + overhang)

    def scaled(self, scale: float) -> "Catalogue":
        """The pixel thresholds at `scale` (masks.pixel_scale: f / depth relative to the tuning
        distance), so a camera further back joins and cuts what one at ~1 m would."""
        from dataclasses import replace

        from perception.masks import scaled_px

        if scale == 1.0:
            return self
        return replace(self, max_join_gap_px=scaled_px(self.max_join_gap_px, scale, 2),
                       l_margin_px=scaled_px(self.l_margin_px, scale, 3))

    def error(self, width: float, height: float) -> float:
        """Largest side error (m) to the closest type face."""
        if not self.faces:
            return math.inf
        return min(max(abs(width - w), abs(height - h)) for w, h in self.faces)

    def matches(self, width: float, height: float, tol: float | None = None) -> bool:
        return self.error(width, height) <= (self.tol if tol is None else tol)

    def error_cut(self, width: float, height: float, cut_axes: set[str] | frozenset[str] = frozenset()) -> float:
        """`error` for a face cut by the image border along `cut_axes` ("x", "z"): a cut side
        is only a lower bound, so it counts only where it is longer than the type's side."""
        if not self.faces:
            return math.inf
        return min(max(max(0.0, width - w) if "x" in cut_axes else abs(width - w),
                       max(0.0, height - h) if "z" in cut_axes else abs(height - h)) for w, h in self.faces)

    def fits(self, width: float, height: float) -> bool:
        """Whether a face of this size fits inside some type face (a part of one)."""
        return any(width <= w + self.tol and height <= h + self.tol for w, h in self.faces)

    def composable(self, width: float, height: float, axis: int, parts: int = 2,
                   staggered: bool = False) -> bool:
        """Whether a face of this size is `parts` type faces in a row: stacked (axis 1, heights
        add up, the widest as wide as it) or side by side (axis 0, widths add up).
        `staggered`: the faces may be offset across the row (a stack of boxes pushed left and
        right), so the row spans at least its widest face and at most all of them side by side."""
        for combo in itertools.combinations_with_replacement(self.faces, parts):
            along = sum(f[1] if axis == 1 else f[0] for f in combo)
            acr = [f[0] if axis == 1 else f[1] for f in combo]
            total, span = (height, width) if axis == 1 else (width, height)
            if abs(along - total) > 1.5 * self.tol:
                continue
            if abs(max(acr) - span) <= self.tol or (
                    staggered and max(acr) - self.tol <= span <= sum(acr) + self.tol):
                return True
        return False

    @property
    def sides(self) -> tuple[float, ...]:
        return tuple(sorted({s for f in self.faces for s in f}))

    def to_json(self) -> dict:
        return {"types": [list(t) for t in self.types], "tol": self.tol}


@dataclass
class _Face:
    mask: np.ndarray
    face: object                      # boxes.FrontFace
    err: float


def _measure(mask: np.ndarray, depth: np.ndarray, camera: Camera, cat: Catalogue,
             cache: dict | None = None) -> _Face | None:
    """The measured face of a mask (memoised per mask object in `cache`)."""
    from perception.boxes import measure_front

    hit = cache.get(id(mask)) if cache is not None else None
    if hit is not None and hit[0] is mask:
        return hit[1]
    f = measure_front(mask, depth, camera)
    out = None if f is None else _Face(mask, f, cat.error(f.width, f.height))
    if cache is not None:
        cache[id(mask)] = (mask, out)   # the mask is kept alive, so its id is not reused
    return out


def apply_catalogue(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, rgb: np.ndarray | None,
                    cat: Catalogue, notes: list[str] | None = None) -> tuple[list[np.ndarray], list]:
    """`join_pieces`, `split_faces`, `cut_l_shapes`, a second join pass,
    `split_stepped_faces`, `take_bridging_parts`, `take_stepped_parts`, `regroup_pieces` (and a join pass after it),
    then `absorb_enclosed`; returns the masks and their measured faces (None where
    a mask cannot be measured), so the pipeline need not measure them again."""
    cache: dict = {}
    notes = notes if notes is not None else []
    masks = [np.asarray(m, bool) for m in masks]
    measured = [_measure(m, depth, camera, cat, cache) for m in masks]
    if not _applies(measured, cat):
        # not a capture of these box types (another warehouse, real data): leave it alone
        return masks, [None if f is None else f.face for f in measured]
    masks = join_pieces(masks, depth, camera, cat, notes, cache)
    n = len(masks)
    masks = split_faces(masks, depth, camera, rgb, cat, notes, cache=cache)
    k = len(notes)
    before = {id(m) for m in masks}
    masks = cut_l_shapes(masks, depth, camera, cat, notes, cache)
    if len(notes) > k:       # an L-cut's rest may be a row of faces the first split saw merged
        masks = split_faces(masks, depth, camera, rgb, cat, notes, cache=cache,
                            only={id(m) for m in masks} - before)
    if len(masks) > n or len(notes) > k:     # a cut piece may join its own face's rest      # a row cut into faces may leave a piece of a face beside its rest
        masks = join_pieces(masks, depth, camera, cat, notes, cache)
    masks = split_stepped_faces(masks, depth, camera, cat, notes, cache)
    masks = take_bridging_parts(masks, depth, camera, cat, notes, cache)
    masks = take_stepped_parts(masks, depth, camera, cat, notes, cache)
    k = len(notes)
    masks = regroup_pieces(masks, depth, camera, rgb, cat, notes, cache)
    if len(notes) > k:      # a piece beside a re-cut face (a label, a tape quarter) may join it now
        masks = join_pieces(masks, depth, camera, cat, notes, cache)
    masks = absorb_enclosed(masks, depth, camera, cat, notes, cache)
    faces = []
    for m in masks:
        f = _measure(m, depth, camera, cat, cache)
        faces.append(None if f is None else f.face)
    return masks, faces


def _applies(measured: list, cat: Catalogue) -> bool:
    """Whether at least `min_share` of the measured faces are type faces, by count or by area
    (a face cut into many pieces by a tape cross must not outvote the faces around it)."""
    ok = [f for f in measured if f is not None]
    area = [float(f.mask.sum()) for f in ok]
    share = max(sum(f.err <= cat.tol for f in ok) / max(len(ok), 1),
                sum(a for f, a in zip(ok, area) if f.err <= cat.tol) / max(sum(area), 1.0))
    return share >= cat.min_share


def catalogue_applies(faces: list, masks: list[np.ndarray], cat: Catalogue) -> bool:
    """Whether a capture whose masks measured as `faces` (boxes.FrontFace, None where not
    measured) shows boxes of these types (see `apply_catalogue`): where it does not (other stock,
    the neura pallet), a face cut by the image border is not completed to a type face either."""
    return _applies([None if f is None else _Face(np.asarray(m, bool), f, cat.error(f.width, f.height))
                     for f, m in zip(faces, masks)], cat)


def _coords(face, mask: np.ndarray, camera: Camera) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Pixels of the mask and their (x, z) on the measured face plane, centred on the face."""
    from perception.boxes import face_axes
    from perception.geometry import ray_plane

    rot = face_axes(face)
    c = np.asarray(face.center, float)
    ys, xs = np.nonzero(mask)
    hit = ray_plane(camera, xs.astype(np.float64), ys.astype(np.float64), c, rot[:, 1])
    rel = hit - c
    return ys, xs, rel @ rot[:, 0], rel @ rot[:, 2]


def _extent(v: np.ndarray, q: float = 0.02) -> float:
    if len(v) < 10:
        return 0.0
    lo, hi = np.quantile(v, (q, 1 - q))
    return float(hi - lo) / (1 - 2 * q)


def _plane_dist(face, mask: np.ndarray, depth: np.ndarray, camera: Camera) -> float:
    """Median distance (m) of the mask's depth points to the plane of `face`."""
    from perception.boxes import face_axes
    from perception.geometry import backproject

    ys, xs = np.nonzero(mask & np.isfinite(depth) & (depth > 0))
    if len(xs) < 10:
        return math.inf
    if len(xs) > 3000:
        st = len(xs) // 3000 + 1
        ys, xs = ys[::st], xs[::st]
    p = backproject(camera, xs.astype(np.float64), ys.astype(np.float64), depth[ys, xs].astype(np.float64))
    n = face_axes(face)[:, 1]
    return float(np.median(np.abs((p - np.asarray(face.center)) @ n)))


def join_pieces(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, cat: Catalogue,
                notes: list[str] | None = None, cache: dict | None = None) -> list[np.ndarray]:
    """Join a piece that is no type face to the neighbour on its plane when the union is one
    (and fills its rectangle): a label, tape end or flap cut off a face."""
    import cv2

    if len(masks) < 2:
        return masks
    masks = [np.asarray(m, bool) for m in masks]
    faces = [_measure(m, depth, camera, cat, cache) for m in masks]
    alive = [f is not None for f in faces]
    # a face cut by the image border is only a lower bound of its size along the cut: its error
    # counts a cut side only where it is too long, and it joins only pieces cut by the same border
    sides = [border_sides(m) for m in masks]

    def err(fc: _Face, m: np.ndarray, sd: tuple[str, ...]) -> float:
        if not sd:
            return fc.err
        axes = {d[1] for d in cut_directions(fc.face, m, camera, sd)}
        return cat.error_cut(fc.face.width, fc.face.height, axes)

    errs = [err(f, m, sd) if f is not None else math.inf for f, m, sd in zip(faces, masks, sides)]
    k = np.ones((2 * cat.max_join_gap_px + 1,) * 2, np.uint8)

    def take(i: int, j: int, fu: _Face, eu: float, note: str) -> None:
        """Mask j becomes the joined face `fu`; piece i is gone."""
        if notes is not None:
            notes.append(note)
        masks[j], faces[j], sides[j], errs[j] = fu.mask, fu, border_sides(fu.mask), eu
        alive[i] = False

    def _group_join(i: int, extra: int | None = None):
        """A face cut into 3+ pieces (a wide tape cross): no two of them fill a rectangle, but
        mask i (a piece, or the cross itself, which may measure as the whole face) and ALL its
        on-plane neighbouring pieces do, and make a type face. `extra`: one more neighbour that
        measures as a type face by chance (a quarter of a 50x17 face cut by a tape cross can
        measure 20x20), counted only within the band the pieces span across it (it may hold a
        strip of the flush box beside the cut face); the union must then be a type face within
        `tol`, and one piece is enough. Returns (j, joined face, error) with the other pieces
        marked dead, or None."""
        near = cv2.dilate(masks[i].astype(np.uint8), k) > 0
        group = [j for j in range(len(masks))
                 if j != i and alive[j] and errs[j] > cat.tol and (near & masks[j]).any()
                 and not ((sides[i] or sides[j]) and not set(sides[i]) & set(sides[j]))
                 and _plane_dist(faces[i].face, masks[j], depth, camera) <= cat.plane_tol]
        if extra is not None:
            group.append(extra)
        if len(group) < (1 if extra is not None else 2):
            return None
        rest = np.zeros_like(masks[i])
        for j in group:
            rest |= masks[j]
        if extra is not None:
            # the chance type face may reach past the cut face into the flush box beside it:
            # it counts only within the band the pieces span across it (on either face axis)
            rest = _band_trim(masks[i] | rest & ~masks[extra], masks[extra], faces[extra].face, camera)
            if rest is None:
                return None
            for j in group:
                if j != extra:
                    rest |= masks[j]
        taken = np.zeros_like(masks[i])
        for q in range(len(masks)):
            if alive[q] and q != i and q not in group:
                taken |= masks[q]
        union, fill = _joined(masks[i], rest, faces[i].face, taken, depth, camera, cat)
        if fill < cat.join_fill:
            return None
        fu = _measure(union, depth, camera, cat, cache)
        if fu is None:
            return None
        eu = err(fu, union, border_sides(union))
        if eu > (cat.join_tol if extra is None else cat.tol):
            return None
        if errs[i] <= cat.tol and max(abs(fu.face.width - faces[i].face.width),
                                      abs(fu.face.height - faces[i].face.height)) > cat.tol:
            return None       # a type face takes pieces only inside its own extent (its arms)
        j = group[0]
        for q in group[1:]:
            alive[q] = False
        return j, fu, eu
    changed = True
    while changed:
        changed = False
        order = sorted((i for i in range(len(masks)) if alive[i] and errs[i] > cat.tol),
                       key=lambda i: int(masks[i].sum()))
        for i in order:
            near = cv2.dilate(masks[i].astype(np.uint8), k) > 0
            best = None
            for j in range(len(masks)):
                if j == i or not alive[j] or not (near & masks[j]).any():
                    continue
                if (sides[i] or sides[j]) and not set(sides[i]) & set(sides[j]):
                    continue
                if _plane_dist(faces[j].face, masks[i], depth, camera) > cat.plane_tol:
                    continue
                taken = np.zeros_like(masks[i])
                for q in range(len(masks)):
                    if alive[q] and q not in (i, j):
                        taken |= masks[q]
                union, fill = _joined(masks[i], masks[j], faces[j].face, taken, depth, camera, cat)
                if fill < cat.join_fill_loose:
                    continue
                fu = _measure(union, depth, camera, cat, cache)
                if fu is None:
                    continue
                eu = err(fu, union, border_sides(union))
                # a rectangle, or (a third piece still missing) a type face to within `tol`
                if fill < cat.join_fill and eu > cat.tol:
                    continue
                # the union is a type face, or (both being pieces) still fits inside one:
                # a face cut into several pieces by tape and labels is joined step by step
                if eu > cat.join_tol and not (errs[j] > cat.tol and cat.fits(fu.face.width, fu.face.height)):
                    continue
                if best is None or (eu > cat.join_tol, eu) < (best[2] > cat.join_tol, best[2]):
                    best = (j, fu, eu)
            if best is None:
                best = _group_join(i)
            if best is None:       # a piece of the cross that measures as a type face by chance
                for t in range(len(masks)):
                    if t == i or not alive[t] or errs[t] > cat.tol or not (near & masks[t]).any() \
                            or ((sides[i] or sides[t]) and not set(sides[i]) & set(sides[t])) \
                            or _plane_dist(faces[i].face, masks[t], depth, camera) > cat.plane_tol:
                        continue
                    best = _group_join(i, extra=t)
                    if best is not None:
                        break
            if best is None:
                continue
            j, fu, eu = best
            take(i, j, fu, eu, f"joined a {faces[i].face.size_cm} "
                               f"piece to its neighbour: {fu.face.size_cm}")
            changed = True
            break
        if not changed:      # a cross measured as the whole face, its quarters as pieces
            for i in sorted((i for i in range(len(masks)) if alive[i] and errs[i] <= cat.tol),
                            key=lambda i: -int(masks[i].sum())):
                g = _group_join(i)
                if g is None:
                    continue
                j, fu, eu = g
                take(i, j, fu, eu, f"joined the pieces of a face cut in several (a tape cross): "
                                   f"{fu.face.size_cm}")
                changed = True
                break
    return [m for m, a in zip(masks, alive) if a]


def _band_trim(pieces: np.ndarray, other: np.ndarray, face, camera: Camera, margin: float = 0.01):
    """`other` cut to the band that `pieces` span along one axis of `face` (the axis that trims
    less of it: at least 2%, at most a third, a strip sticking out), or None when neither does."""
    _, _, px, pz = _coords(face, pieces, camera)
    ys, xs, ox, oz = _coords(face, other, camera)
    if len(px) < 10 or len(ox) < 10:
        return None
    best = None
    for p, o in ((pz, oz), (px, ox)):
        lo, hi = np.quantile(p, (0.01, 0.99))
        keep = (o >= lo - margin) & (o <= hi + margin)
        if 0.02 * len(o) <= (~keep).sum() <= len(o) / 3 and (best is None or keep.sum() > best.sum()):
            best = keep
    if best is None:
        return None
    out = np.zeros_like(other)
    out[ys[best], xs[best]] = True
    return out


def _joined(a: np.ndarray, b: np.ndarray, face, taken: np.ndarray, depth: np.ndarray, camera: Camera,
            cat: Catalogue) -> tuple[np.ndarray, float]:
    """Two pieces joined with the unclaimed pixels between them that lie on their plane (a
    label, a tape edge, the depth holes of a seam), within the union's min-area rectangle;
    and how well that fills the rectangle."""
    import cv2

    from perception.boxes import face_axes
    from perception.geometry import backproject

    u = a | b
    rows = np.flatnonzero(u.any(axis=1))
    cols = np.flatnonzero(u.any(axis=0))
    y0, y1 = max(0, rows[0] - 2), min(u.shape[0], rows[-1] + 3)
    x0, x1 = max(0, cols[0] - 2), min(u.shape[1], cols[-1] + 3)
    uc = u[y0:y1, x0:x1]
    sub = cv2.morphologyEx(uc.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    pts = cv2.findNonZero(sub)
    if pts is None:
        return u, 0.0
    rect = np.zeros(uc.shape, np.uint8)
    cv2.fillPoly(rect, [np.round(cv2.boxPoints(cv2.minAreaRect(pts))).astype(np.int32)], 1)
    rect = rect > 0
    d = depth[y0:y1, x0:x1]
    free = rect & ~uc & ~taken[y0:y1, x0:x1] & np.isfinite(d) & (d > 0)
    cand = uc & rect
    ys, xs = np.nonzero(free)
    if len(xs):
        p = backproject(camera, (xs + x0).astype(np.float64), (ys + y0).astype(np.float64),
                        d[ys, xs].astype(np.float64))
        on = np.abs((p - np.asarray(face.center)) @ face_axes(face)[:, 1]) < cat.plane_tol
        cand[ys[on], xs[on]] = True
    fill = float(cand.sum()) / max(float(rect.sum()), 1.0)
    n, lbl, stats, _ = cv2.connectedComponentsWithStats(cand.astype(np.uint8), connectivity=4)
    if n > 2:
        cand = lbl == 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
    ac, bc = a[y0:y1, x0:x1], b[y0:y1, x0:x1]
    if (cand & ac).sum() < 0.9 * ac.sum() or (cand & bc).sum() < 0.9 * bc.sum():
        return u, 0.0          # the pieces do not connect on their plane
    out = np.zeros_like(u)
    out[y0:y1, x0:x1] = cand | (uc & ~rect)
    return out, fill


def split_faces(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, rgb: np.ndarray | None,
                cat: Catalogue, notes: list[str] | None = None, max_parts: int = 4,
                cache: dict | None = None, only: set[int] | None = None) -> list[np.ndarray]:
    """Split a mask that is no type face at the line where it falls into two type faces,
    when a seam (colour edge line or depth step) runs along that line; `only`: ids of the
    masks to look at (the rest are kept as they are)."""
    import cv2

    lab = None
    if rgb is not None:
        lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
        lab[..., 1:] = (lab[..., 1:] - 128) * 2
    out: list[np.ndarray] = []
    for m in masks:
        if only is not None and id(m) not in only:
            out.append(m)
            continue
        out.extend(_split_one(np.asarray(m, bool), depth, camera, lab, cat, notes, max_parts, cache,
                              others=masks))
    return out


def _split_one(mask: np.ndarray, depth: np.ndarray, camera: Camera, lab: np.ndarray | None,
               cat: Catalogue, notes: list[str] | None, budget: int,
               cache: dict | None = None, row_axis: int | None = None,
               others: list[np.ndarray] | None = None) -> list[np.ndarray]:
    """`row_axis`: the mask is the rest of a row of faces cut off a longer mask along this
    axis; it may then also split into a type face and a piece of one (its other part was cut
    off the same face by the segmenter, and `join_pieces` joins them again)."""
    if budget <= 1:
        return [mask]
    f = _measure(mask, depth, camera, cat, cache)
    if f is None or f.err <= cat.tol:
        return [mask]
    face = f.face
    side_min = min(cat.sides) - cat.tol
    if max(face.width, face.height) < 2 * side_min:
        return [mask]
    ys, xs, cx, cz = _coords(face, mask, camera)
    cands_ok: list[tuple] = []
    for axis in (1, 0):                        # stacked (split along z) first, then side by side
        t = cz if axis == 1 else cx
        o = cx if axis == 1 else cz
        lo, hi = np.quantile(t, (0.01, 0.99))
        length = hi - lo
        if length < 2 * side_min:
            continue
        cands = set()
        for s in cat.sides:
            for pos in (lo + s, hi - s):
                if lo + side_min <= pos <= hi - side_min:
                    cands.add(round(float(pos), 3))
        if not cands:
            continue
        # seam evidence per 3 mm bin: the fraction of 1 cm strips across the face that hold an
        # edge pixel at that position, and the depth step across it
        ev = _line_evidence(t, o, ys, xs, lab, depth, camera, face, cat)
        for pos in sorted(cands):
            for p2, score, step in _peaks(ev, pos, 0.015, cat):
                a = t < p2
                if a.sum() < 50 or (~a).sum() < 50:
                    continue
                wa, ha = (_extent(cx[a]), _extent(cz[a]))
                wb, hb = (_extent(cx[~a]), _extent(cz[~a]))
                if axis == 1:
                    ha, hb = p2 - np.quantile(t[a], 0.01), np.quantile(t[~a], 0.99) - p2
                else:
                    wa, wb = p2 - np.quantile(t[a], 0.01), np.quantile(t[~a], 0.99) - p2
                ea, eb = cat.error(wa, ha), cat.error(wb, hb)
                # two flush faces of one colour leave only a faint seam: a mask far off every type
                # face that falls into exactly two type faces there is cut on weaker evidence
                need = cat.weak_evidence if f.err > cat.row_margin and max(ea, eb) <= cat.tol else 1.0
                if score < need or min(ea, eb) > cat.tol:
                    continue
                rest = (wb, hb) if ea <= cat.tol else (wa, ha)
                # (the weakest case: its type face must match to half the tolerance)
                # (or, for any mask, when the piece joins a neighbour that is itself a piece:
                # the segmenter cut a face and gave one part to the box beside it)
                piece = ((row_axis in (axis, None)) and max(ea, eb) > cat.tol and cat.fits(*rest)
                         and min(rest) >= 0.05 and min(ea, eb) <= cat.tol / 2)
                piece = piece and ("row" if row_axis == axis else "pieces")
                stagger = False
                if max(ea, eb) > cat.tol and not piece:
                    # one part a type face, the other (budget left) itself two faces in a row
                    # along the same axis: a stack of three flush boxes is cut one seam at a time
                    # (only for a mask far off any type face: a face measured a few cm too
                    # long, labels on it, is not a stack of smaller faces)
                    if f.err <= cat.row_margin or min(ea, eb) > cat.tol:
                        continue
                    if not any(cat.composable(rest[0], rest[1], axis, k) for k in range(2, budget)):
                        # a staircase: faces of one colour stacked with offsets (a real seam
                        # needed, and kept only if the rest cuts into type faces down to the last)
                        if score < 1.0 or not any(cat.composable(rest[0], rest[1], axis, k, staggered=True)
                                                  for k in range(2, budget)):
                            continue
                        stagger = True
                # a depth step is two fronts (a label or tape edge is flat): it beats colour alone;
                # a faint seam (under 1, `weak_evidence`) only where no real seam gives a cut
                key = (score >= 1.0, max(ea, eb) <= cat.tol, step, score, -max(ea, eb))
                cands_ok.append((key, axis, p2, a, wa, ha, wb, hb, ea, eb, piece, stagger))
    best = None
    staircase = None
    for c in sorted(cands_ok, key=lambda c: (not c[11],) + c[0], reverse=True):
        pa = np.zeros_like(mask)
        pb = np.zeros_like(mask)
        pa[ys[c[3]], xs[c[3]]] = True
        pb[ys[~c[3]], xs[~c[3]]] = True
        # a piece must join a neighbour into a type face, else the cut is at a label or tape
        if c[10] and not _piece_joins(pa if c[8] > cat.tol else pb, pb if c[8] > cat.tol else pa, others or [],
                                      depth, camera, cat, cache, pieces_only=c[10] == "pieces"):
            continue
        if c[11]:
            rest_m = pb if c[8] <= cat.tol else pa
            sub: list[str] = []
            parts = _split_one(rest_m, depth, camera, lab, cat, sub, budget - 1, cache, None, others)
            errs = [_measure(q, depth, camera, cat, cache) for q in parts]
            if len(parts) < 2 or any(e is None or e.err > cat.tol for e in errs):
                continue
            staircase = (pa if c[8] <= cat.tol else pb, parts, sub)
        best = c
        break
    if best is None:
        return [mask]
    _, axis, p2, a, wa, ha, wb, hb, ea, eb, _, _ = best
    if staircase is not None:
        if notes is not None:
            notes.append(f"split a {face.size_cm} staircase of faces {'across' if axis == 1 else 'down'} "
                         f"its seams into {len(staircase[1]) + 1} type faces")
            notes.extend(staircase[2])
        return [staircase[0]] + staircase[1]
    if notes is not None:
        notes.append(f"split a {face.size_cm} face "
                     f"{'across' if axis == 1 else 'down'} its seam into {wa * 100:.0f}x{ha * 100:.0f} and "
                     f"{wb * 100:.0f}x{hb * 100:.0f} cm (evidence {best[0][3]:.2f}{', depth step' if best[0][2] else ''})")
    return (_split_one(pa, depth, camera, lab, cat, notes, budget - 1, cache, axis if ea > cat.tol else None, others)
            + _split_one(pb, depth, camera, lab, cat, notes, budget - 1, cache, axis if eb > cat.tol else None,
                         others))


def _piece_joins(piece: np.ndarray, rest: np.ndarray, others: list[np.ndarray], depth: np.ndarray,
                 camera: Camera, cat: Catalogue, cache: dict | None, pieces_only: bool = False) -> bool:
    """Whether a piece, joined with a neighbouring mask on its plane (not taking pixels of
    `rest` or of other masks), makes a type face that fills its rectangle (`pieces_only`: a
    neighbour that is itself no type face)."""
    import cv2

    k = np.ones((2 * cat.max_join_gap_px + 1,) * 2, np.uint8)
    near = cv2.dilate(piece.astype(np.uint8), k) > 0
    for m in others:
        if (m & piece).any() or not (near & m).any():
            continue
        fm = _measure(m, depth, camera, cat, cache)
        if fm is None or (pieces_only and fm.err <= cat.tol) \
                or _plane_dist(fm.face, piece, depth, camera) > cat.plane_tol:
            continue
        taken = rest.copy()
        for q in others:
            if q is not m:
                taken |= q & ~piece
        union, fill = _joined(piece, m, fm.face, taken, depth, camera, cat)
        if fill < cat.join_fill:
            continue
        fu = _measure(union, depth, camera, cat, None)
        if fu is not None and fu.err <= cat.tol:
            return True
    return False


@dataclass
class _Evidence:
    bins: np.ndarray        # bin centres (m)
    score: np.ndarray       # seam score per bin: 1 = the weakest seam taken
    depth: np.ndarray | None = None   # the depth step's share of it (a step >= depth_step is 1)


def _line_evidence(t, o, ys, xs, lab, depth, camera, face, cat: Catalogue,
                   bin_m: float = 0.003) -> _Evidence:
    """How much a seam runs across the face at each position along `t`.

    Colour: the mean colour of each 3 mm band across the face (texture and grain
    average out along the band, a seam line does not): a band that differs from
    the bands 9 mm either side, or a colour step across it, in units of the
    profile's own robust noise. Depth: the step of the mean plane residual
    across the position.
    """
    from perception.boxes import face_axes
    from perception.geometry import backproject

    lo, hi = float(t.min()), float(t.max())
    nb = max(1, int(math.ceil((hi - lo) / bin_m)))
    bi = np.clip(((t - lo) / bin_m).astype(int), 0, nb - 1)
    olo, ohi = np.quantile(o, (0.08, 0.92))
    inner = (o > olo) & (o < ohi)
    cnt = np.bincount(bi[inner], minlength=nb).astype(float)
    good = cnt >= 5
    score = np.zeros(nb)
    r, w = 3, 5
    if lab is not None and good.sum() > 4 * w:
        col = lab[ys[inner], xs[inner]].astype(np.float64)
        for c in range(3):
            prof = np.bincount(bi[inner], weights=col[:, c], minlength=nb) / np.maximum(cnt, 1)
            idx = np.arange(nb)
            prof = np.interp(idx, idx[good], prof[good])
            line = np.zeros(nb)
            line[r:-r] = prof[r:-r] - 0.5 * (prof[:-2 * r] + prof[2 * r:])
            cs = np.concatenate([[0], np.cumsum(prof)])
            stp = np.zeros(nb)
            k = np.arange(w, nb - w)
            stp[k] = (cs[k] - cs[k - w]) / w - (cs[k + w + 1] - cs[k + 1]) / w
            for v in (line, stp):
                core = v[w:-w] if nb > 2 * w else v
                noise = 1.4826 * float(np.median(np.abs(core - np.median(core)))) + 0.3
                score = np.maximum(score, np.abs(v) / (noise * cat.min_evidence))
    d = depth[ys, xs].astype(np.float64)
    ok = np.isfinite(d) & (d > 0) & inner
    dscore = np.zeros(nb)
    if ok.sum() > 50:
        p = backproject(camera, xs[ok].astype(np.float64), ys[ok].astype(np.float64), d[ok])
        res = (p - np.asarray(face.center)) @ face_axes(face)[:, 1]
        s_ = np.bincount(bi[ok], weights=res, minlength=nb)
        c_ = np.bincount(bi[ok], minlength=nb).astype(float)
        cs, cc = np.concatenate([[0], np.cumsum(s_)]), np.concatenate([[0], np.cumsum(c_)])
        for k in range(w, nb - w):
            n1, n2 = cc[k] - cc[k - w], cc[k + w + 1] - cc[k + 1]
            if n1 > 10 and n2 > 10:
                stp = abs((cs[k] - cs[k - w]) / n1 - (cs[k + w + 1] - cs[k + 1]) / n2)
                dscore[k] = stp / cat.depth_step
                score[k] = max(score[k], dscore[k])
    return _Evidence(lo + (np.arange(nb) + 0.5) * bin_m, score, dscore)


def _peaks(ev: _Evidence, pos: float, win: float, cat: Catalogue) -> list[tuple[float, float, bool]]:
    """The best seam position within `win` of `pos`, its score (>= 1 means a seam) and whether
    a depth step (>= depth_step) runs there."""
    sel = np.flatnonzero(np.abs(ev.bins - pos) <= win)
    if len(sel) == 0:
        return []
    score = ev.score[sel]
    k = int(np.argmax(score))
    step = ev.depth is not None and bool(ev.depth[sel[k]] >= 1.0)
    return [(float(ev.bins[sel[k]]), float(score[k]), step)]


def cut_directions(face, mask: np.ndarray, camera: Camera, sides: tuple[str, ...] | None = None,
                   margin: int = 2) -> set[str]:
    """The face sides ("+x", "-x", "+z", "-z" on the face's width/height axes) that an image
    border cuts: per border the mask runs into, the side its border pixels lie on (their median
    cast onto the face plane, relative to the half extent)."""
    out: set[str] = set()
    for side in (border_sides(mask, margin) if sides is None else sides):
        px = border_pixels(mask, side, margin)
        if int(px.sum()) < 3:
            continue
        _, _, cx, cz = _coords(face, px, camera)
        if not len(cx):
            continue
        rx = float(np.median(cx)) / max(face.width / 2, 1e-6)
        rz = float(np.median(cz)) / max(face.height / 2, 1e-6)
        if max(abs(rx), abs(rz)) < 0.25:
            continue        # border pixels in the middle of the face: cannot tell
        out.add(("+x" if rx > 0 else "-x") if abs(rx) >= abs(rz) else ("+z" if rz > 0 else "-z"))
    return out


def complete_cut_face(face, mask: np.ndarray, camera: Camera, cat: Catalogue | None,
                      sides: tuple[str, ...] | None = None, min_side: float = 0.02):
    """A face cut by the image border, completed where the catalogue explains it.

    The face is at least as big as seen. Cut along one axis only (its other side seen whole),
    it becomes the smallest type face whose uncut side matches (within `tol`) and whose cut
    side is at least as long as seen, grown away from the border; otherwise it keeps its seen
    size, but no side under `min_side` (a strip along the border still stands for a box).
    Returns (face, cut directions, how it was completed or None)."""
    from dataclasses import replace

    from perception.boxes import face_axes

    cut = cut_directions(face, mask, camera, sides)
    w, h = face.width, face.height
    how = None
    axes = {d[1] for d in cut}
    if cat is not None and len(axes) == 1:
        ax = axes.pop()
        seen, other = (h, w) if ax == "z" else (w, h)
        cands = [(f[1], f[0]) if ax == "z" else (f[0], f[1]) for f in cat.faces]   # (cut side, uncut side)
        cands = [c for c in cands if abs(c[1] - other) <= cat.tol and c[0] >= seen - cat.tol]
        if cands:
            full = max(min(cands)[0], seen)
            if ax == "z":
                h = full
            else:
                w = full
            how = "type"
    w, h = max(w, min_side), max(h, min_side)
    if (w, h) == (face.width, face.height):
        return face, cut, None
    rot = face_axes(face)
    shift = np.zeros(3)
    for d in cut:
        col = rot[:, 0] if d[1] == "x" else rot[:, 2]
        grow = (w - face.width) if d[1] == "x" else (h - face.height)
        if (("+" + d[1]) in cut) and (("-" + d[1]) in cut):
            continue        # cut on both ends: grow about the centre
        shift += (1.0 if d[0] == "+" else -1.0) * col * grow / 2
    c = tuple(float(v) for v in np.asarray(face.center) + shift)
    return replace(face, center=c, width=float(w), height=float(h)), cut, how or "min"


def _rect_fill(m: np.ndarray) -> float:
    """Area over the area of the axis-aligned bounding rectangle (image rows/columns)."""
    rows = np.flatnonzero(m.any(axis=1))
    cols = np.flatnonzero(m.any(axis=0))
    if len(rows) == 0:
        return 0.0
    return float(m.sum()) / float((rows[-1] - rows[0] + 1) * (cols[-1] - cols[0] + 1))


def _rotated(ys: np.ndarray, xs: np.ndarray, deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates in image axes turned by `deg` (0: columns, rows)."""
    if deg == 0.0:
        return xs.astype(np.float64), ys.astype(np.float64)
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return xs * c + ys * s, ys * c - xs * s


def _fill_at(ys: np.ndarray, xs: np.ndarray, deg: float) -> float:
    """Pixel count over the area of the rectangle turned by `deg` around the pixels."""
    u, v = _rotated(ys, xs, deg)
    if not len(u):
        return 0.0
    return float(len(u)) / float((np.ptp(u) + 1) * (np.ptp(v) + 1))


def _best_l_cut(ys: np.ndarray, xs: np.ndarray, deg: float, margin: int,
                part_fill: float, step: bool = False) -> list[tuple[float, int, np.ndarray]]:
    """Per axis of the frame turned by `deg`: the straight cut (at least `margin` px in from
    either end) whose two parts both fill their turned rectangles best (>= `part_fill`), as
    (score, axis, pixels on the near side); at 0 deg this is a cut along an image row/column.
    `step`: also the cut where the extent across it jumps most, one part filling >= `part_fill`."""
    u, v = _rotated(ys, xs, deg)
    out = []
    for axis, (t, o) in enumerate(((v, u), (u, v))):
        bi = np.floor(t - t.min() + 1e-9).astype(int)
        nb = int(bi.max()) + 1
        cnt = np.bincount(bi, minlength=nb).astype(float)
        omin = np.full(nb, np.inf)
        omax = np.full(nb, -np.inf)
        np.minimum.at(omin, bi, o)
        np.maximum.at(omax, bi, o)
        tmin = np.full(nb, np.inf)
        tmax = np.full(nb, -np.inf)
        np.minimum.at(tmin, bi, t)
        np.maximum.at(tmax, bi, t)
        # part a: bins < pos; part b: bins >= pos
        ca, cb = np.cumsum(cnt), np.cumsum(cnt[::-1])[::-1]
        amin, amax = np.minimum.accumulate(omin), np.maximum.accumulate(omax)
        bmin, bmax = np.minimum.accumulate(omin[::-1])[::-1], np.maximum.accumulate(omax[::-1])[::-1]
        atmax = np.maximum.accumulate(tmax)
        btmin = np.minimum.accumulate(tmin[::-1])[::-1]
        best = None
        for pos in range(margin, nb - margin + 1):
            if pos <= 0 or pos >= nb or ca[pos - 1] == 0 or cb[pos] == 0:
                continue
            fa = ca[pos - 1] / ((atmax[pos - 1] - t.min() + 1) * (amax[pos - 1] - amin[pos - 1] + 1))
            fb = cb[pos] / ((t.max() - btmin[pos] + 1) * (bmax[pos] - bmin[pos] + 1))
            score = min(fa, fb)
            if score >= part_fill and (best is None or score > best[0]):
                best = (float(score), pos)
        if best is not None:
            out.append((best[0], axis, bi < best[1]))
        if step:
            # the L's corner: where the mask's extent across the line jumps most (a part may be
            # ragged, a label edge or tape along it, so long as the other fills its rectangle)
            span = np.where(cnt > 0, omax - omin + 1, 0.0)
            jump = None
            for pos in range(max(margin, 1), nb - max(margin, 1) + 1):
                lo, hi = span[max(0, pos - margin):pos], span[pos:pos + margin]
                if not len(lo) or not len(hi) or ca[pos - 1] == 0 or cb[pos] == 0:
                    continue
                fa = ca[pos - 1] / ((atmax[pos - 1] - t.min() + 1) * (amax[pos - 1] - amin[pos - 1] + 1))
                fb = cb[pos] / ((t.max() - btmin[pos] + 1) * (bmax[pos] - bmin[pos] + 1))
                d = abs(float(np.median(lo)) - float(np.median(hi)))
                if max(fa, fb) >= part_fill and (jump is None or d > jump[0]):
                    jump = (d, pos)
            if jump is not None and (best is None or jump[1] != best[1]):
                out.append((0.0, axis, bi < jump[1]))
    return out


def cut_l_shapes(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, cat: Catalogue,
                 notes: list[str] | None = None, cache: dict | None = None,
                 max_fill: float = 0.8, part_fill: float = 0.8,
                 angles: tuple[float, ...] = ()) -> list[np.ndarray]:
    """Cut an L-shaped mask (no type face, filling its rectangle < `max_fill`: the strip of one
    box merged with the end of another) along a straight line that leaves two rectangles,
    and keep the cut only when a part joins a neighbouring mask into a type face (within `tol`,
    filling its rectangle >= `join_fill`; never a union that merely fits inside one).

    The line runs along an image row or column where both parts fill their rectangles
    >= `part_fill`; where no such cut joins, at the L's corner (where the mask's extent across
    the line jumps most, one part filling >= `part_fill`): a strip whose edge to the rest of
    its face is ragged (a label or tape split between them) fills no rectangle. `angles` (deg,
    off by default) also tries lines turned by each angle (the mask filling its turned
    rectangle < `max_fill`): on a test a turned cut joined a union holding 11% of another
    box, and the framed shelf it was meant for (perceive_plan seed 11) needs no turned line."""
    out = list(masks)
    k = np.ones((2 * cat.max_join_gap_px + 1,) * 2, np.uint8)
    i = 0
    while i < len(out):
        m = out[i]
        f = _measure(m, depth, camera, cat, cache)
        if f is None or f.err <= cat.tol or border_sides(m) or _rect_fill(m) >= max_fill:
            i += 1
            continue
        ys, xs = np.nonzero(m)
        others = [o for j, o in enumerate(out) if j != i]
        joined = None
        for deg, step in ((0.0, False),) + tuple((a, True) for a in (0.0,) + tuple(angles)):
            if deg != 0.0 and _fill_at(ys, xs, deg) >= max_fill:
                continue          # a rectangle at this angle: not an L
            cuts = []
            for _, _, near_side in _best_l_cut(ys, xs, deg, cat.l_margin_px, part_fill, step):
                a = np.zeros_like(m)
                a[ys[near_side], xs[near_side]] = True
                cuts += [(a, m & ~a), (m & ~a, a)]
            joined = _l_join(cuts, others, depth, camera, cat, cache, k)
            if joined is not None:
                break
        if joined is None:
            i += 1
            continue
        piece, rest, j, fu = joined
        if notes is not None:
            notes.append(f"cut an L-shaped {f.face.size_cm} mask in two"
                         f"{'' if deg == 0.0 else f' (line turned {deg:+.0f} deg)'}; "
                         f"a part joined its neighbour into a {fu.face.size_cm} type face")
        others[j] = fu.mask
        out = others[:i] + [rest] + others[i:]
        i = 0
    return out


def _l_join(cuts, others, depth, camera, cat, cache, k):
    """The best (piece, rest, neighbour index, joined face) among the cuts: the piece joins
    a neighbour on its plane into a type face filling its rectangle; None if none does."""
    import cv2

    joined = None
    for piece, rest in cuts:
        near = cv2.dilate(piece.astype(np.uint8), k) > 0
        for j, o in enumerate(others):
            if not (near & o).any():
                continue
            fo = _measure(o, depth, camera, cat, cache)
            if fo is None or _plane_dist(fo.face, piece, depth, camera) > cat.plane_tol:
                continue
            taken = rest.copy()
            for q in others:
                if q is not o:
                    taken |= q
            union, fill = _joined(piece, o, fo.face, taken, depth, camera, cat)
            if fill < cat.join_fill:
                continue
            fu = _measure(union, depth, camera, cat, None)
            if fu is not None and fu.err <= cat.tol and (joined is None or fu.err < joined[3].err):
                joined = (piece, rest, j, fu)
    return joined


def _neighbour_pieces(i: int, masks: list[np.ndarray], kernel: np.ndarray, depth: np.ndarray,
                      camera: Camera, cat: Catalogue, cache: dict | None, plane=None) -> list[int]:
    """Indices of the masks next to mask i (within the join gap) that are pieces: measurable, no
    type face, not cut by the image border; with `plane` (a face), only those on its plane."""
    import cv2

    near = cv2.dilate(masks[i].astype(np.uint8), kernel) > 0
    out = []
    for j, o in enumerate(masks):
        if j == i or border_sides(o) or not (near & o).any():
            continue
        fo = _measure(o, depth, camera, cat, cache)
        if fo is None or fo.err <= cat.tol:
            continue
        if plane is not None and _plane_dist(plane, o, depth, camera) > cat.plane_tol:
            continue
        out.append(j)
    return out


def split_stepped_faces(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, cat: Catalogue,
                        notes: list[str] | None = None, cache: dict | None = None,
                        min_part: float = 0.05) -> list[np.ndarray]:
    """Split a mask that measures as a type face but is two boxes: the left halves of two
    stacked faces, each cut down one line by the segmenter, merged into one mask that happens
    to have a type face's size (17x50 cm from two 23x25 faces).

    `split_faces` never looks at such a mask (it is a type face), so this runs once the pieces
    are as joined as they get. The mask splits only at a depth step (>= `depth_step`, two
    fronts; a label edge is flat) running across it, each part at least `min_part` long, and
    only when BOTH parts join a different neighbouring piece (no type face itself) on the
    part's own plane into a type face filling its rectangle >= `join_fill`; the three masks
    become the two joined faces."""
    out = [np.asarray(m, bool) for m in masks]
    if len(out) < 3:
        return out
    k = np.ones((2 * cat.max_join_gap_px + 1,) * 2, np.uint8)
    i = 0
    while i < len(out):
        m = out[i]
        f = _measure(m, depth, camera, cat, cache)
        if f is None or f.err > cat.tol or border_sides(m):
            i += 1
            continue
        pieces = _neighbour_pieces(i, out, k, depth, camera, cat, cache)
        done = None
        if len(pieces) >= 2:
            done = _stepped_split(m, i, f, pieces, out, depth, camera, cat, cache, k, min_part)
        if done is None:
            i += 1
            continue
        (ja, ua), (jb, ub), axis, step = done
        if notes is not None:
            fa, fb = _measure(ua, depth, camera, cat, cache), _measure(ub, depth, camera, cat, cache)
            notes.append(f"split a {f.face.size_cm} type-face mask "
                         f"{'across' if axis == 1 else 'down'} a {step * 100:.1f} cm depth step; its parts "
                         f"joined their neighbouring pieces into {fa.face.size_cm} and {fb.face.size_cm} faces")
        out = [o for j, o in enumerate(out) if j not in (i, ja, jb)] + [ua, ub]
        i = 0
    return out


def _stepped_split(m, i, f, pieces, out, depth, camera, cat, cache, k, min_part):
    """((piece a, union a), (piece b, union b), axis, step in m) for the best depth-step line
    through mask `m` whose two parts each join one of `pieces` into a type face; else None."""
    import cv2

    ys, xs, cx, cz = _coords(f.face, m, camera)
    best = None
    for axis in (1, 0):
        t, o = (cz, cx) if axis == 1 else (cx, cz)
        lo, hi = np.quantile(t, (0.01, 0.99))
        if hi - lo < 2 * min_part:
            continue
        ev = _line_evidence(t, o, ys, xs, None, depth, camera, f.face, cat)
        sel = np.flatnonzero((ev.bins >= lo + min_part) & (ev.bins <= hi - min_part) & (ev.depth >= 1.0))
        if not len(sel):
            continue
        pk = int(sel[np.argmax(ev.depth[sel])])
        a = t < ev.bins[pk]
        parts = []
        for sel_ in (a, ~a):
            p = np.zeros_like(m)
            p[ys[sel_], xs[sel_]] = True
            parts.append(p)
        joins = []
        for p, rest in ((parts[0], parts[1]), (parts[1], parts[0])):
            fp = _measure(p, depth, camera, cat, None)
            if fp is None:
                break
            nearp = cv2.dilate(p.astype(np.uint8), k) > 0
            cand = None
            for j in pieces:
                if not (nearp & out[j]).any() or _plane_dist(fp.face, out[j], depth, camera) > cat.plane_tol:
                    continue
                taken = rest.copy()
                for q, oq in enumerate(out):
                    if q not in (i, j):
                        taken |= oq
                union, fill = _joined(p, out[j], fp.face, taken, depth, camera, cat)
                if fill < cat.join_fill:
                    continue
                fu = _measure(union, depth, camera, cat, None)
                if fu is not None and fu.err <= cat.tol and (cand is None or fu.err < cand[2]):
                    cand = (j, union, fu.err)
            if cand is None:
                break
            joins.append(cand)
        if len(joins) < 2 or joins[0][0] == joins[1][0]:
            continue
        step = float(ev.depth[pk]) * cat.depth_step
        if best is None or step > best[3]:
            best = ((joins[0][0], joins[0][1]), (joins[1][0], joins[1][1]), axis, step)
    return best


def take_bridging_parts(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, cat: Catalogue,
                        notes: list[str] | None = None, cache: dict | None = None) -> list[np.ndarray]:
    """Give a face back the part of another mask that lies inside its rectangle: a tape band
    across a face, merged with the flush face above it (same colour, same plane), leaves the
    face as two pieces on either side of the band and a T-shaped mask that is no type face.

    For a mask that is no type face with >= 2 neighbouring pieces (no type faces, on its
    plane): the pieces' joint rectangle is their face; the mask's pixels inside it go to the
    pieces only when the pieces and that part join into a type face filling its rectangle
    >= `join_fill` AND what is left of the mask is a type face (within `tol`)."""
    def attempt(i, m, f, out, k):
        pieces = _neighbour_pieces(i, out, k, depth, camera, cat, cache, plane=f.face)
        done = _bridge(m, i, pieces, out, depth, camera, cat, cache) if len(pieces) >= 2 else None
        if done is None:
            return None
        rest, union, fr, fu = done
        return pieces, rest, union, (f"gave the part of a {f.face.size_cm} mask inside {len(pieces)} pieces' "
                                     f"rectangle to them: {fu.face.size_cm} and {fr.face.size_cm}")

    return _give_parts(masks, depth, camera, cat, cache, notes, 3, attempt)


def _give_parts(masks, depth, camera, cat, cache, notes, least, attempt) -> list[np.ndarray]:
    """The loop shared by the passes that give part of a non-type mask to neighbouring pieces:
    for each mask that is no type face and not cut by the image border, `attempt(i, mask, face,
    masks, kernel)` returns (indices of the pieces it used, what is left of the mask, the joined
    face, a note) or None; after a change the scan starts again."""
    out = [np.asarray(m, bool) for m in masks]
    if len(out) < least:
        return out
    k = np.ones((2 * cat.max_join_gap_px + 1,) * 2, np.uint8)
    i = 0
    while i < len(out):
        m = out[i]
        f = _measure(m, depth, camera, cat, cache)
        done = None if f is None or f.err <= cat.tol or border_sides(m) else attempt(i, m, f, out, k)
        if done is None:
            i += 1
            continue
        used, rest, union, note = done
        if notes is not None:
            notes.append(note)
        out = [o for j, o in enumerate(out) if j != i and j not in used] + [rest, union]
        i = 0
    return out


def _bridge(m, i, pieces, out, depth, camera, cat, cache):
    """(rest of m, joined face mask, their faces) or None; see `take_bridging_parts`."""
    import cv2

    grp = np.zeros_like(m)
    for j in pieces:
        grp |= out[j]
    pts = cv2.findNonZero(grp.astype(np.uint8))
    rect = np.zeros(m.shape, np.uint8)
    cv2.fillPoly(rect, [np.round(cv2.boxPoints(cv2.minAreaRect(pts))).astype(np.int32)], 1)
    part = m & (rect > 0)
    rest = m & ~part
    if part.sum() < 0.05 * m.sum() or rest.sum() < 0.3 * m.sum():
        return None
    # what is left must stay one piece (drop a thin fringe along the rectangle's edge)
    n, lbl, stats, _ = cv2.connectedComponentsWithStats(rest.astype(np.uint8), connectivity=4)
    if n > 2:
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        if stats[big, cv2.CC_STAT_AREA] < 0.95 * rest.sum():
            return None
        part |= rest & (lbl != big)
        rest = lbl == big
    fg = _measure(out[pieces[0]], depth, camera, cat, cache)
    done = _part_to_pieces(rest, part, grp, fg.face, i, pieces, out, depth, camera, cat)
    if done is None:
        return None
    fr, union, fu = done
    return rest, union, fr, fu


def _part_to_pieces(rest, part, grp, face, i, used, out, depth, camera, cat):
    """(rest's face, the pieces `grp` joined with `part` on `face`, that face) when what is left
    of mask i is a type face filling its rectangle and the join is a type face too; else None."""
    fr = _measure(rest, depth, camera, cat, None)
    if fr is None or fr.err > cat.tol or _rect_fill(rest) < cat.join_fill:
        return None
    taken = rest.copy()
    for q, oq in enumerate(out):
        if q != i and q not in used:
            taken |= oq
    union, fill = _joined(part, grp, face, taken, depth, camera, cat)
    if fill < cat.join_fill:
        return None
    fu = _measure(union, depth, camera, cat, None)
    if fu is None or fu.err > cat.tol:
        return None
    return fr, union, fu


def take_stepped_parts(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, cat: Catalogue,
                       notes: list[str] | None = None, cache: dict | None = None,
                       plane_tol: float = 0.006) -> list[np.ndarray]:
    """Give pieces of a face back the part of another mask that lies on their plane, a depth
    step away from the rest of that mask: a face cut by a tape band whose part below the band
    merged with the box beneath it (same colour, a front 1-3 cm nearer or further: under the
    depth-gap split of `masks.refine`); `take_bridging_parts` misses it because that part lies
    outside the pieces' rectangle.

    For a mask that is no type face (not cut by the image border) with neighbouring pieces (no
    type faces) on one plane (the group grown through the pieces' own neighbours): its pixels
    within `plane_tol` of that plane and nearer to it than to the plane of the mask's other
    pixels (where a yawed face's plane crosses it, a pixel goes with its nearest clear
    neighbour), connected to the pieces, go to them; only when what is left of the mask lies off
    that plane (median distance > `cat.plane_tol`) and is a type face filling its rectangle >=
    `join_fill`, and the pieces with that part join into a type face filling its rectangle >=
    `join_fill`."""
    def attempt(i, m, f, out, k):
        pieces = _neighbour_pieces(i, out, k, depth, camera, cat, cache)
        done = _stepped_part(m, i, pieces, out, depth, camera, cat, cache, k, plane_tol) if pieces else None
        if done is None:
            return None
        rest, union, grp, fr, fu, step = done
        return grp, rest, union, (f"gave the part of a {f.face.size_cm} mask {step * 100:.1f} cm off its rest "
                                  f"to {len(grp)} neighbouring piece(s): {fu.face.size_cm} and {fr.face.size_cm}")

    return _give_parts(masks, depth, camera, cat, cache, notes, 2, attempt)


def _stepped_part(m, i, pieces, out, depth, camera, cat, cache, kernel, plane_tol):
    """(rest of m, joined face mask, piece indices, their faces, depth step) or None; see
    `take_stepped_parts`."""
    import cv2

    fa = max((_measure(out[j], depth, camera, cat, cache) for j in pieces), key=lambda q: int(q.mask.sum()))
    grp = [j for j in pieces if _plane_dist(fa.face, out[j], depth, camera) <= cat.plane_tol]
    gm = np.zeros_like(m)
    for j in grp:
        gm |= out[j]
    grown = True
    while grown:       # the other pieces of that face: neighbours of the group on its plane
        grown = False
        near = cv2.dilate(gm.astype(np.uint8), kernel) > 0
        for q, oq in enumerate(out):
            if q == i or q in grp or border_sides(oq) or not (near & oq).any():
                continue
            fq = _measure(oq, depth, camera, cat, cache)
            if fq is None or fq.err <= cat.tol or _plane_dist(fa.face, oq, depth, camera) > cat.plane_tol:
                continue
            grp.append(q)
            gm |= oq
            grown = True
    # each pixel to the nearer plane: the pieces' one, or the one of the mask's part off it
    on = _on_plane(fa.face, m, depth, camera, plane_tol)
    fr0 = _measure(m & ~on, depth, camera, cat, None)
    if fr0 is None:
        return None
    dp, dr = _plane_res(fa.face, m, depth, camera), _plane_res(fr0.face, m, depth, camera)
    on = m & (dp <= plane_tol) & (dp + 0.003 < dr)
    off = m & (dr + 0.003 < dp)
    # where the two planes cross (a yawed face), neither is nearer: such a pixel goes with the
    # nearest pixel that is clearly on one of them
    amb = m & ~on & ~off
    if amb.any() and on.any() and off.any():
        d_on = cv2.distanceTransform((~on).astype(np.uint8), cv2.DIST_L2, 3)
        d_off = cv2.distanceTransform((~off).astype(np.uint8), cv2.DIST_L2, 3)
        on = on | (amb & (d_on < d_off))
    on = cv2.morphologyEx(on.astype(np.uint8), cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)) > 0
    near = cv2.dilate(gm.astype(np.uint8), kernel) > 0
    n, lbl = cv2.connectedComponents(on.astype(np.uint8), connectivity=4)
    touch = np.unique(lbl[near & on])
    part = np.isin(lbl, touch[touch > 0])
    part = m & (cv2.morphologyEx(part.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0)
    rest = m & ~part
    if part.sum() < 0.05 * m.sum() or rest.sum() < 0.3 * m.sum():
        return None
    n, lbl, stats, _ = cv2.connectedComponentsWithStats(rest.astype(np.uint8), connectivity=4)
    if n > 2:
        big = 1 + int(np.argmax(stats[1:, cv2.CC_STAT_AREA]))
        if stats[big, cv2.CC_STAT_AREA] < 0.95 * rest.sum():
            return None
        # specks next to the part are its holes; others (on the rest's rim) are dropped
        specks = rest & (lbl != big)
        n2, lbl2 = cv2.connectedComponents(specks.astype(np.uint8), connectivity=8)
        grow = cv2.dilate(part.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        touch = np.unique(lbl2[grow & specks])
        part |= np.isin(lbl2, touch[touch > 0])
        rest = lbl == big
    step = _plane_dist(fa.face, rest, depth, camera)
    if step <= cat.plane_tol:
        return None          # no depth step: a label or tape edge, not two fronts
    done = _part_to_pieces(rest, part, gm, fa.face, i, grp, out, depth, camera, cat)
    if done is None:
        return None
    fr, union, fu = done
    return rest, union, grp, fr, fu, step


def regroup_pieces(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, rgb: np.ndarray | None,
                   cat: Catalogue, notes: list[str] | None = None, cache: dict | None = None,
                   max_group: int = 4) -> list[np.ndarray]:
    """Re-cut neighbouring masks that are no type faces along the faces' own seams: two stacked
    cubes, each cut down its vertical tape, whose left halves and right halves merged (two
    10x40 masks for two 20x20 faces); a face whose tape band gave its halves to the faces
    above and below.

    For a mask that is no type face and its neighbouring masks on its plane that are no type
    faces either (a pair first, then all of them, up to `max_group`): their union (with the
    unclaimed on-plane pixels between them) fills its rectangle >= `join_fill` and is cut by
    `split_faces`' rule (sides within `join_tol`: masks grown apart measure a little wide) into
    parts that are ALL type faces within `tol`; the masks become those parts. Nothing is done
    where a part would be no type face."""
    import cv2

    out = [np.asarray(m, bool) for m in masks]
    if len(out) < 2:
        return out
    lab = None
    if rgb is not None:
        lab = cv2.cvtColor(rgb, cv2.COLOR_RGB2LAB).astype(np.float32)
        lab[..., 1:] = (lab[..., 1:] - 128) * 2
    k = np.ones((2 * cat.max_join_gap_px + 1,) * 2, np.uint8)
    tried: set[frozenset] = set()
    i = 0
    while i < len(out):
        m = out[i]
        f = _measure(m, depth, camera, cat, cache)
        if f is None or f.err <= cat.tol or border_sides(m):
            i += 1
            continue
        near = _neighbour_pieces(i, out, k, depth, camera, cat, cache, plane=f.face)
        groups = [[j] for j in near]
        if 2 <= len(near) <= max_group - 1:
            groups.append(near)
        done = None
        for g in groups:
            key = frozenset(id(out[q]) for q in [i] + g)
            if key in tried:
                continue
            tried.add(key)
            done = _regroup(i, g, out, f, depth, camera, lab, cat, cache)
            if done is not None:
                break
        if done is None:
            i += 1
            continue
        group, parts = done
        if notes is not None:
            sizes = [_measure(p, depth, camera, cat, cache).face.size_cm for p in parts]
            notes.append(f"re-cut {len(group)} masks that are no type faces "
                         f"({', '.join(_measure(out[q], depth, camera, cat, cache).face.size_cm for q in group)}) "
                         f"along their seams into {', '.join(sizes)} faces")
        out = [o for q, o in enumerate(out) if q not in group] + parts
        i = 0
    return out


def _regroup(i, g, out, f, depth, camera, lab, cat, cache):
    """(indices of the masks, the type-face parts) when mask i and masks `g` re-cut into type
    faces only; else None. See `regroup_pieces`."""
    group = [i] + list(g)
    rest = np.zeros_like(out[i])
    for q in g:
        rest |= out[q]
    taken = np.zeros_like(out[i])
    for q, o in enumerate(out):
        if q not in group:
            taken |= o
    union, fill = _joined(out[i], rest, f.face, taken, depth, camera, cat)
    if fill < cat.join_fill:
        return None
    fu = _measure(union, depth, camera, cat, None)
    if fu is None or fu.err <= cat.tol:
        return None         # a type face: `join_pieces`' business
    others = [o for q, o in enumerate(out) if q not in group]
    # the parts of masks grown apart may measure a little wide: cut at `join_tol`, as for a join,
    # but keep the cut only when every part is a type face within `tol`
    from dataclasses import replace

    parts = _split_one(union, depth, camera, lab, replace(cat, tol=cat.join_tol), None, 4, None, None, others)
    if len(parts) < 2 or len(parts) < len(group) - 1:
        return None
    for p in parts:
        fp = _measure(p, depth, camera, cat, None)
        if fp is None or fp.err > cat.tol:
            return None
    return group, parts


def absorb_enclosed(masks: list[np.ndarray], depth: np.ndarray, camera: Camera, cat: Catalogue,
                    notes: list[str] | None = None, cache: dict | None = None,
                    ring_px: int = 3, enclosed: float = 0.75, surround: float = 0.6) -> list[np.ndarray]:
    """Give a piece (no type face) that another mask on its plane surrounds to that mask: a
    label or a tape band inside a face whose mask is itself a little off its type (it took a
    strip of the box below), so no join makes a type face of them. A box's face is never
    inside another box's face on one plane, so the piece needs no type to be explained.

    Surrounded: >= `enclosed` of the `ring_px` ring around the piece is that mask (counting only
    ring pixels of masks or on the mask's plane: the gap to the background at a box's edge does
    not count) and >= `surround` of the whole ring; the mask is at least twice the piece's area,
    and the piece lies on its plane."""
    import cv2

    out = [np.asarray(m, bool) for m in masks]
    if len(out) < 2:
        return out
    k = np.ones((2 * ring_px + 1,) * 2, np.uint8)
    changed = True
    while changed:
        changed = False
        for i, m in enumerate(out):
            f = _measure(m, depth, camera, cat, cache)
            if f is None or f.err <= cat.tol or border_sides(m):
                continue
            ring = (cv2.dilate(m.astype(np.uint8), k) > 0) & ~m
            if not ring.any():
                continue
            claimed = np.zeros_like(ring)
            for j, o in enumerate(out):
                if j != i:
                    claimed |= ring & o
            for j, o in enumerate(out):
                if j == i or not (ring & o).any() or o.sum() < 2 * m.sum():
                    continue
                fo = _measure(o, depth, camera, cat, cache)
                if fo is None or _plane_dist(fo.face, m, depth, camera) > cat.plane_tol:
                    continue
                # the ring that counts: pixels of any mask, or on the mask's plane (a gap to the
                # background or a box further back around a face's edge does not)
                # and the mask itself must lie all round it (a part of a face at its edge, beside
                # the mask on one side only, is no label)
                n = int((claimed | (ring & _on_plane(fo.face, ring, depth, camera, cat.plane_tol))).sum())
                hit = int((ring & o).sum())
                if n == 0 or hit < enclosed * n or hit < surround * int(ring.sum()):
                    continue
                if notes is not None:
                    notes.append(f"gave a {f.face.size_cm} piece inside a {fo.face.size_cm} mask to it")
                out[j] = o | m
                out.pop(i)
                changed = True
                break
            if changed:
                break
    return out


def _plane_res(face, where: np.ndarray, depth: np.ndarray, camera: Camera) -> np.ndarray:
    """Per pixel of `where`, the distance (m) of its depth point to the plane of `face`
    (inf where there is no depth or outside `where`)."""
    from perception.boxes import face_axes
    from perception.geometry import backproject

    out = np.full(where.shape, np.inf)
    ys, xs = np.nonzero(where & np.isfinite(depth) & (depth > 0))
    if len(xs):
        p = backproject(camera, xs.astype(np.float64), ys.astype(np.float64), depth[ys, xs].astype(np.float64))
        out[ys, xs] = np.abs((p - np.asarray(face.center)) @ face_axes(face)[:, 1])
    return out


def _on_plane(face, where: np.ndarray, depth: np.ndarray, camera: Camera, tol: float) -> np.ndarray:
    """The pixels of `where` whose depth point lies within `tol` of the plane of `face`."""
    from perception.boxes import face_axes
    from perception.geometry import backproject

    out = np.zeros_like(where)
    ys, xs = np.nonzero(where & np.isfinite(depth) & (depth > 0))
    if len(xs):
        p = backproject(camera, xs.astype(np.float64), ys.astype(np.float64), depth[ys, xs].astype(np.float64))
        near = np.abs((p - np.asarray(face.center)) @ face_axes(face)[:, 1]) <= tol
        out[ys[near], xs[near]] = True
    return out
