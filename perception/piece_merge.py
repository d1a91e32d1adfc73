"""Joining the pieces that the depth-and-edge segmenter's cuts left into whole faces.

Two rules, both only where the union is still a rectangle (`rect_fill`):
- tape (`merge_tape`): a thin band (or cross) of another colour across a face, near its
  middle, joins the same-colour pieces it separates;
- colour (`merge_pieces`): neighbouring pieces of one colour join, unless both are
  rectangles with a colour edge all along their common border (`seam_fraction`: the seam
  between two flush boxes).
Used by `perception.segment_depth`; apart from it because it is its own idea (what is one
face), not how the image is cut.
"""
from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from shelfpick.perception.depth_edge_config import DepthEdgeConfig
from shelfpick.perception.pixels import hull_candidates, label_percentiles


def merge_pieces(assigned: np.ndarray, core: np.ndarray, patch: np.ndarray, lab: np.ndarray,
                 cfg: DepthEdgeConfig, edges: np.ndarray | None = None) -> np.ndarray:
    """Join neighbouring pieces (labels in `assigned`) whose mean Lab colours over `core` are
    within `colour_merge`, closest first, while their union fills its rectangle (`rect_fill`);
    two rectangles with an edge line along their common border (`seam_veto`) stay apart."""
    n = int(assigned.max())
    if n <= 1:
        return assigned
    _, mean = _colours(assigned, core, lab, n)
    union = _Unions(assigned, n)
    # neighbouring pieces (one pixel apart after growing)
    borders = _borders(assigned)
    pairs = set(contacts(assigned, borders))
    parent = list(range(n + 1))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    cand = []
    for a, b in pairs:
        de = float(np.linalg.norm(mean[a - 1] - mean[b - 1]))
        if de < cfg.colour_merge:
            cand.append((de, a, b))
    cand.sort()
    members: dict[int, list[int]] = {i: [i] for i in range(1, n + 1)}
    seam = seam_fraction(assigned, edges, borders) if edges is not None and cfg.seam_veto < 1 else {}
    for _, a, b in cand:
        ra, rb = find(a), find(b)
        if ra == rb:
            continue
        if seam.get((a, b), 0.0) > cfg.seam_veto and \
                min(rect_fill(union(members[r])[0]) for r in (ra, rb)) >= cfg.seam_rect:
            continue        # two rectangles with an edge line all along their border: two boxes
        if rect_fill(union(members[ra] + members[rb])[0]) < cfg.rect_fill:
            continue
        parent[rb] = ra
        members[ra] = members[ra] + members.pop(rb)
    lut = np.zeros(n + 1, np.int32)
    for i in range(1, n + 1):
        lut[i] = find(i)
    return lut.take(assigned)           # lut[assigned], by take


def _colours(labels: np.ndarray, core: np.ndarray, lab: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """(pixel count, at least 1; mean Lab colour) of pieces 1..n over `core`: one selection of
    the core's labelled pixels for the count and the three channels' sums, the very numbers of
    `label_sums(lab[..., c], np.where(core, labels, 0), 1..n)` (bincount adds each label's values
    in pixel order, and the order and values are the same) without selecting them four times."""
    on = np.flatnonzero(core & (labels != 0))
    keys = labels.ravel().take(on)
    cnt = np.maximum(np.bincount(keys, minlength=n + 1)[1:n + 1], 1)
    px = lab.reshape(-1, lab.shape[-1]).take(on, axis=0)
    mean = np.stack([np.bincount(keys, weights=px[:, c], minlength=n + 1)[1:n + 1] / cnt for c in range(3)], axis=1)
    return cnt, mean


class _Unions:
    """`np.isin(labels, ids)` worked out in the ids' joint bounding box only (their boxes found
    once, when first asked: `ndimage.find_objects`), with that box: outside it no pixel is one
    of them, and `rect_fill` and a median over it see the same pixels in the same order."""

    def __init__(self, labels: np.ndarray, n: int) -> None:
        self.labels, self.n = labels, n
        self.boxes: list | None = None

    def __call__(self, ids: list[int]) -> tuple[np.ndarray, tuple[slice, slice]]:
        if self.boxes is None:
            self.boxes = ndimage.find_objects(self.labels, max_label=self.n)
        got = [self.boxes[i - 1] for i in ids if 0 < i <= self.n and self.boxes[i - 1] is not None]
        if not got:                      # none of them is in the image: one pixel that is not one
            win = (slice(0, 1), slice(0, 1))
        else:
            win = tuple(slice(min(w[k].start for w in got), max(w[k].stop for w in got)) for k in (0, 1))
        return np.isin(self.labels[win], ids), win

    def full(self, part: np.ndarray, win: tuple[slice, slice]) -> np.ndarray:
        """A mask of the box `win` put back in a frame-sized one."""
        out = np.zeros(self.labels.shape, bool)
        out[win] = part
        return out


# a pixel and its right neighbour, a pixel and the one below it
_SHIFTS = ((np.s_[:, :-1], np.s_[:, 1:]), (np.s_[:-1, :], np.s_[1:, :]))


def _borders(labels: np.ndarray) -> list[np.ndarray]:
    """Where two pieces meet, for each of `_SHIFTS`: the pixel and its neighbour are labelled
    and differ (found once a call for the contacts, the seams and the thickness)."""
    return [(labels[s] != labels[t]) & (labels[s] > 0) & (labels[t] > 0) for s, t in _SHIFTS]


def _pair_codes(labels: np.ndarray, n: int, s: tuple, t: tuple, sel: np.ndarray) -> np.ndarray:
    """The pair (smaller label, larger label) of each border pixel `sel` of one shift, as one
    integer: smaller * (n + 1) + larger."""
    a, b = labels[s][sel], labels[t][sel]
    return np.minimum(a, b).astype(np.int64) * (n + 1) + np.maximum(a, b)


def contacts(labels: np.ndarray, borders: list[np.ndarray]) -> dict[tuple[int, int], int]:
    """(a, b) with a < b -> number of 4-neighbour pixel pairs where label a touches label b
    (`borders`: the labels' `_borders`)."""
    n = int(labels.max())
    out: dict[tuple[int, int], int] = {}
    for (s, t), sel in zip(_SHIFTS, borders):
        if not sel.any():
            continue
        u, c = np.unique(_pair_codes(labels, n, s, t, sel), return_counts=True)
        for k, v in zip(u, c):
            key = (int(k // (n + 1)), int(k % (n + 1)))
            out[key] = out.get(key, 0) + int(v)
    return out


def merge_tape(labels: np.ndarray, core: np.ndarray, lab: np.ndarray, mpp: np.ndarray,
               cfg: DepthEdgeConfig) -> np.ndarray:
    """Join a tape piece with the pieces it separates.

    Tape across a face (a band, or a cross of two) is a piece of another colour
    that cuts the face into parts of one colour. A piece P is taken for tape when
    it is thin (<= `tape_max_m`, and clearly thinner than its neighbours), at least
    two of its neighbours share a colour, and P with those neighbours fills a
    rectangle. Two stacked boxes flush with a thin third one between them would
    fool this rule only if the outer two have the same colour and width.
    """
    n = int(labels.max())
    if n < 3:
        return labels
    idx = np.arange(1, n + 1)
    borders = _borders(labels)
    thick = _thickness(labels, mpp, idx, borders)
    cnt, mean = _colours(labels, core, lab, n)
    touch = contacts(labels, borders)
    union = _Unions(labels, n)
    nbrs: dict[int, set[int]] = {i: set() for i in idx}
    for (a, b), c in touch.items():
        if c >= 3:
            nbrs[a].add(b)
            nbrs[b].add(a)
    lut = np.arange(n + 1)
    done: set[int] = set()
    for p in sorted(idx, key=lambda i: thick[i - 1]):
        p = int(p)
        if p in done or thick[p - 1] > cfg.tape_max_m:
            continue
        cand = [q for q in nbrs[p] if q not in done
                and thick[p - 1] <= cfg.tape_rel * thick[q - 1]]
        if len(cand) < 2:
            continue
        best = _same_colour(cand, cnt, mean, cfg.tape_colour)
        if best is None:
            continue
        best = _tape_group(union, p, best, touch, thick[p - 1], mpp, cfg)
        if best is None:
            continue
        for q in best:
            lut[q] = p
            done.add(q)
        done.add(p)
    return lut.take(labels)             # lut[labels], by take


def _thickness(labels: np.ndarray, mpp: np.ndarray, idx: np.ndarray, borders: list[np.ndarray]) -> np.ndarray:
    """Per label: twice the 90th percentile of the distance (m) to another label or the
    background. Depth holes inside a face are no borders (closed first); the 90th percentile,
    not the maximum: the centre of a tape cross is wider than its arms. `borders`: the labels'
    `_borders`."""
    fgl = labels > 0
    filled = cv2.morphologyEx(fgl.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)) > 0
    border = ~filled
    for (s, t), diff in zip(_SHIFTS, borders):
        border[s] |= diff
        border[t] |= diff
    inner = ~border
    dist = cv2.distanceTransform(inner.astype(np.uint8), cv2.DIST_L2, 3)
    # uint16 labels where they fit: label_percentiles' stable argsort of them is numpy's radix
    # sort, ~3x faster than of int32/int64 ones, and a stable sort's order is the same
    small = labels.astype(np.uint16) if len(idx) and idx[-1] < 2 ** 16 else labels
    return 2 * label_percentiles(dist * mpp, small, idx, 90)


def _same_colour(cand: list[int], cnt: np.ndarray, mean: np.ndarray, tol: float) -> list[int] | None:
    """The candidates within `tol` (Lab) of the largest one that has at least one such
    neighbour (largest first); None when no two share a colour."""
    for seed in sorted(cand, key=lambda q: -cnt[q - 1]):
        group = [q for q in cand
                 if np.linalg.norm(mean[q - 1] - mean[seed - 1]) < tol]
        if len(group) >= 2:
            return group
    return None


def _tape_group(unions: _Unions, p: int, best: list[int], touch: dict[tuple[int, int], int],
                thick_p: float, mpp: np.ndarray, cfg: DepthEdgeConfig) -> list[int] | None:
    """The pieces tape `p` joins: those along its long sides first (not one it only touches
    with its end), else all of `best`; when tape and pieces fill a rectangle and the tape
    spans it (`spans`). None: no tape here."""
    side = [q for q in best if touch[(min(p, q), max(p, q))]
            >= 0.3 * max(touch[(min(p, r), max(p, r))] for r in best)]
    for group in ([side, best] if len(side) >= 2 and len(side) < len(best) else [best]):
        union, win = unions([p] + group)
        if rect_fill(union) >= cfg.rect_fill and spans(
                unions.full(unions.labels[win] == p, win), unions.full(union, win), cfg.tape_span,
                thick_p / max(float(np.median(mpp[win][union])), 1e-6), cfg.tape_frac, cfg.tape_centre):
            return group
    return None


def spans(piece: np.ndarray, union: np.ndarray, frac: float, thick_px: float = 0.0,
          max_rel: float = 1.0, centre_tol: float = 1.0) -> bool:
    """Whether `piece` looks like tape on the face `union`: it runs across the face along one
    of its rectangle axes (>= `frac` of the face), is thin across that axis (<= `max_rel` of the
    face) and lies near the middle of the face (tape closes the flaps' centre seam)."""
    pts = cv2.findNonZero(piece.astype(np.uint8))
    upts = cv2.findNonZero(union.astype(np.uint8))
    if pts is None or upts is None:
        return False
    (_, _), (_, _), ang = cv2.minAreaRect(pts)
    a = np.deg2rad(ang)
    axes = (np.array([np.cos(a), np.sin(a)]), np.array([-np.sin(a), np.cos(a)]))
    ext = []
    for ax in axes:
        pp = pts.reshape(-1, 2) @ ax
        uu = upts.reshape(-1, 2) @ ax
        ext.append((np.percentile(pp, 1), np.percentile(pp, 99), np.percentile(uu, 1), np.percentile(uu, 99)))
    for i in (0, 1):
        p0, p1, u0, u1 = ext[i]
        if u1 - u0 <= 0 or p1 - p0 < frac * (u1 - u0):
            continue
        q0, q1, v0, v1 = ext[1 - i]
        if v1 - v0 <= 0:
            continue
        width = min(q1 - q0, thick_px) if thick_px > 0 else q1 - q0
        centre = abs(0.5 * (q0 + q1) - 0.5 * (v0 + v1)) / (v1 - v0)
        if width <= max_rel * (v1 - v0) and centre <= centre_tol:
            return True
    return False


def seam_fraction(labels: np.ndarray, edges: np.ndarray, borders: list[np.ndarray]) -> dict[tuple[int, int], float]:
    """(a, b) -> fraction of the border between pieces a and b that runs along a colour edge
    (`borders`: the labels' `_borders`).

    Two pieces of one face cut apart by a thin tape meet at the tape's middle, away
    from any edge; two boxes meet at their seam, which is an edge line all along.
    """
    n = int(labels.max())
    tot: dict[int, int] = {}
    hit: dict[int, int] = {}
    for (s, t), sel in zip(_SHIFTS, borders):
        if not sel.any():
            continue
        e = (edges[s][sel] | edges[t][sel]).astype(np.int64)
        u, inv = np.unique(_pair_codes(labels, n, s, t, sel), return_inverse=True)
        t = np.bincount(inv)
        h = np.bincount(inv, weights=e)
        for k, tt, hh in zip(u, t, h):
            tot[int(k)] = tot.get(int(k), 0) + int(tt)
            hit[int(k)] = hit.get(int(k), 0) + int(hh)
    return {(k // (n + 1), k % (n + 1)): hit[k] / tot[k] for k in tot if tot[k] >= 10}


def rect_fill(mask: np.ndarray) -> float:
    """How well the mask fills its min-area rectangle: the rectangle of the mask opened by
    5x5 (one-pixel spurs left by growing must not inflate it), depth holes closed."""
    pts = cv2.findNonZero(mask.astype(np.uint8))
    if pts is None:
        return 0.0
    x, y, w, h = cv2.boundingRect(pts)
    sub = np.pad(mask[y:y + h, x:x + w].astype(np.uint8), 3)
    sub = cv2.morphologyEx(sub, cv2.MORPH_CLOSE, np.ones((3, 3), np.uint8))
    core = cv2.morphologyEx(sub, cv2.MORPH_OPEN, np.ones((5, 5), np.uint8))
    cpts = hull_candidates(core)
    if cpts is None:
        return 0.0
    rect = cv2.minAreaRect(cpts)
    box = np.zeros_like(sub)
    cv2.fillPoly(box, [np.round(cv2.boxPoints(rect)).astype(np.int32)], 1)
    return float((sub & box).sum()) / max(float(box.sum()), 1.0)
