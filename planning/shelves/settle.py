"""Settling a laid-out shelf in the physics simulation, and checking it is a truth: at rest where
it was placed, and still at rest when read back into a fresh simulation."""
from __future__ import annotations

import math
import warnings

from shelfpick.perception.errors import SceneError
from shelfpick.perception.scene import Scene
from shelfpick.planning.geometry3 import rot_angle_deg
from shelfpick.planning.shelves.placement import GAP
from shelfpick.planning.sim import ShelfSim

STILL_TIME = 1.0                     # a settled shelf left alone this long ...
STILL_LIMIT = 0.01                   # ... moves no box more than this, or it is dropped
SETTLE_MOVE_LIMIT = 0.03             # a box that moved more than this while settling: drop the scene
SETTLE_TURN_LIMIT = 12.0             # degrees


def _reload_problem(scene: Scene) -> str:
    """A shelf written is a truth: read back into a fresh simulation it must come to rest where it
    is (a column rocking on a light box can pass the first settle and not the next). '' when it does."""

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            sim = ShelfSim(scene)
        except SceneError as exc:
            return f"read back, it does not stand: {exc}"
    try:
        after = {b.id: b.position for b in sim.scene.boxes}
        gone = set(scene.ids) - set(sim.present())
    finally:
        sim.close()
    moved = max((math.dist(b.position, after[b.id]) for b in scene.boxes if b.id in after), default=0.0)
    if gone or moved > STILL_LIMIT:
        return f"read back, boxes moved {moved * 100:.1f} cm or fell ({sorted(gone)})"
    return ""


def _settle(scene: Scene) -> Scene:
    """Settle in the physics simulation; SceneError if it does not rest or boxes moved far."""

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ShelfSim(scene)
    try:
        settled = sim.scene
        present = set(sim.present())
        drift = sim.idle(STILL_TIME) if present == set(scene.ids) else {}
    finally:
        sim.close()
    creeping = {b: d for b, d in drift.items() if d > STILL_LIMIT}
    if creeping:
        worst = max(creeping, key=creeping.get)
        raise SceneError(f"box {worst} still moves {creeping[worst] * 100:.1f} cm in {STILL_TIME:.0f} s "
                         f"after settling: the shelf is not at rest")
    if present != set(scene.ids):
        raise SceneError(f"boxes fell off while settling: {sorted(set(scene.ids) - present)}")
    after = {b.id: b for b in settled.boxes}
    for b in scene.boxes:
        a = after[b.id]
        # every box was placed GAP above what holds it: a stack of k boxes sinks by about k * GAP
        sink = GAP * (1 + (b.position[2] - b.size[2] / 2) / 0.17)
        side = math.hypot(a.position[0] - b.position[0], a.position[1] - b.position[1])
        drop = b.position[2] - a.position[2]
        move = max(side, abs(drop) - sink if drop > 0 else -drop)
        turn = rot_angle_deg(a.orientation, b.orientation)
        if move > SETTLE_MOVE_LIMIT or turn > SETTLE_TURN_LIMIT:
            raise SceneError(f"box {b.id} moved {move * 100:.1f} cm / {turn:.0f} deg while settling")
        if min(c[2] for c in a.corners()) < -0.01:
            raise SceneError(f"box {b.id} fell below the shelf floor")
    return settled
