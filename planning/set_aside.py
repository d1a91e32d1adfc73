"""Perceived faces no sample world can hold, set aside as unexplained matter (issue 31).

When two perceived faces overlap deeper than any world repairs, even built exactly as
perceived with no drawn error, at least one of them is wrong, and the image cannot say
which. Refusing the whole shelf throws away every plan that never comes near them. So
the boxes the overlap names are taken out of the scene and put back as unexplained matter
(planning/unexplained.py): a static obstacle in every sample world from their seen faces
back to the wall, and a plan whose pulled box, or a box it moves, comes near it is not
declared safe. Refused as before:

- a target among them (nobody can say what the suction cup would pull);
- a scene that gives depths (a scene file, not an image: the file is wrong);
- a scene that needs more than `MAX_SET_ASIDE` boxes set aside (most of it is wrong).
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable, Mapping, Sequence, TypeVar

from shelfpick.perception.errors import SceneError
from shelfpick.perception.scene import Box, Camera, Scene, Unexplained
from shelfpick.planning.overlap_repair import OverlapError

if TYPE_CHECKING:  # pragma: no cover
    from shelfpick.planning.plan import Plan

T = TypeVar("T")

MAX_SET_ASIDE = 4     # boxes: two contradictory pairs; a shelf with more is mostly misperceived


def _front_corners(b: Box) -> list[tuple[float, float, float]]:
    """The four corners of the face on the box's local -y side (the face the camera saw)."""
    cs = b.corners()          # ordered sx, sy, sz: the local -y corners are 0, 1, 4, 5
    return [cs[i] for i in (0, 1, 4, 5)]


def _pixels(area: float, distance: float, camera: Camera | None) -> int:
    """About how many depth pixels a face of `area` m^2 at `distance` m covered (1 when the scene
    has no camera): the record needs a count, and the face's own mask is not in the scene."""
    if camera is None or distance <= 0:
        return 1
    return max(1, round(area * camera.fx * camera.fy / distance ** 2))


def face_region(b: Box, camera: Camera | None, why: str) -> Unexplained:
    """Box `b`'s seen face as unexplained matter: one column over its x-z extent, at its
    nearest y (planning takes it back to the back wall)."""
    fc = _front_corners(b)
    lo = tuple(min(c[k] for c in fc) for k in range(3))
    hi = tuple(max(c[k] for c in fc) for k in range(3))
    area = b.size[0] * b.size[2]
    dist = float((b.extra.get("perceived") or {}).get("distance") or 0.0)
    return Unexplained(f"aside-{b.id}", lo, hi, _pixels(area, dist, camera), round(area, 5),  # type: ignore[arg-type]
                       ((lo[0], hi[0], lo[2], hi[2], lo[1]),), why)


def set_aside(scene: Scene, ids: tuple[str, ...], why: str) -> Scene:
    """`scene` with the boxes `ids` taken out and their faces added to its unexplained matter."""
    regions = tuple(face_region(scene.box(i), scene.camera, f"set aside by the planner: {why}") for i in ids)
    return replace(scene.without(ids), unexplained=tuple(scene.unexplained or ()) + regions)


@dataclass(frozen=True)
class SetAside:
    """A scene as given, the scene planned on (`planned`: the given one with `entries`' boxes set
    aside) and what was set aside and why (`{"boxes": [...], "why": "..."}` each)."""

    given: Scene
    planned: Scene
    entries: tuple[dict[str, Any], ...] = ()

    @classmethod
    def from_entries(cls, given: Scene, entries: "Sequence[Mapping[str, Any]]") -> "SetAside":
        """What a plan's record (`extra["set_aside"]`) says was set aside, rebuilt on the scene it
        was given, as `build_setting_aside` built it (an entry's boxes the scene no longer has, or
        already set aside by an earlier entry, are skipped): a view or a replay draws from it."""
        planned, kept = given, []
        for e in entries:
            ids = tuple(b for b in dict.fromkeys(e.get("boxes", ())) if b in planned.ids)
            if ids:
                planned = set_aside(planned, ids, str(e.get("why", "")))
                kept.append({"boxes": list(ids), "why": str(e.get("why", ""))})
        return cls(given, planned, tuple(kept))

    def boxes(self) -> set[str]:
        return {b for e in self.entries for b in e["boxes"]}

    def regions(self) -> tuple[Unexplained, ...]:
        """The matter the set-aside faces became (the planned scene's regions the given one lacks)."""
        given = set(self.given.unexplained or ())
        return tuple(u for u in self.planned.unexplained or () if u not in given)

    def refuse(self, target: str | None) -> None:
        """SceneError when `target` was set aside: no plan can pull a face that cannot be right."""
        for e in self.entries:
            if target in e["boxes"]:
                raise SceneError(f"{target} was set aside, its face and another cannot all be right "
                                 f"({e['why']}): no plan can pull it; capture again")

    def record(self, plan: "Plan") -> "Plan":
        """`plan`, made on `planned`, told what was set aside (`extra["set_aside"]`) and bound to the
        scene it was given (`provenance.scene_hash`)."""
        from shelfpick.planning.plan import scene_hash

        if not self.entries:
            return plan
        extra = {**plan.extra, "set_aside": [dict(e) for e in self.entries]}
        if isinstance(extra.get("provenance"), dict):
            extra["provenance"] = {**extra["provenance"], "scene_hash": scene_hash(self.given)}
        return replace(plan, extra=extra)


def build_setting_aside(scene: Scene, target: str | None, build: Callable[[Scene], T]) -> tuple[T, SetAside]:
    """`build(scene)`, setting aside the boxes of each overlap past repair it raises and building
    again; (what it built, what was set aside). The overlap comes back when it may not be set
    aside (see the module docstring)."""
    planned, entries = scene, []
    while True:
        try:
            return build(planned), SetAside(scene, planned, tuple(entries))
        except OverlapError as exc:
            names = tuple(b for b in dict.fromkeys(exc.boxes) if b in planned.ids)
            n = sum(len(e["boxes"]) for e in entries) + len(names)
            if planned.depth_known or not names or target in names or n > MAX_SET_ASIDE:
                raise
            planned = set_aside(planned, names, exc.detail)
            entries.append({"boxes": list(names), "why": exc.detail})
            warnings.warn(f"set aside {' and '.join(names)} as unexplained matter: no world holds their faces as "
                          f"perceived ({exc.detail}); a plan that comes near them is not declared safe", stacklevel=2)
