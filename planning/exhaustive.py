"""Ground truth for small scenes: the fewest removals that get a target out with no collapse.

Breadth-first search over *sets* of removed boxes: a state is reachable when
some order of pulling its boxes kept every step collapse-free. The first
level at which the target itself comes out safely is the minimum. With n
boxes there are at most 2^(n-1) states, so this is for small scenes (the
benchmark uses it up to about 8 boxes to report the gap between the physics
planner and the true optimum, and which tasks admit any collapse-free order).

``min_removals`` is physics-free (it takes ``safe(removed, box) -> bool``);
``true_scene_oracle`` is that function on a ground-truth scene in PyBullet.
"""
from __future__ import annotations

from collections import deque
from typing import Callable, Iterable

from shelfpick.perception.scene import Scene
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.sim import ShelfSim

SafeFn = Callable[[frozenset[str], str], bool]

MAX_BOXES = 10


def min_removals(ids: Iterable[str], target: str, safe: SafeFn,
                 max_boxes: int = MAX_BOXES) -> tuple[str, ...] | None:
    """Shortest collapse-free sequence ending with ``target``, or None when none exists.

    Among sequences of equal length the first found in the given id order wins,
    so the answer is deterministic. Scenes above ``max_boxes`` are refused
    (the search is exponential).
    """
    boxes = tuple(dict.fromkeys(ids))
    if target not in boxes:
        raise ValueError(f"target {target!r} is not among the boxes {boxes!r}")
    if len(boxes) > max_boxes:
        raise ValueError(f"exhaustive search is for scenes of at most {max_boxes} boxes, got {len(boxes)}")
    others = [b for b in boxes if b != target]
    start: frozenset[str] = frozenset()
    parent: dict[frozenset[str], tuple[frozenset[str], str] | None] = {start: None}
    queue = deque([start])
    while queue:
        state = queue.popleft()
        if safe(state, target):
            path = [target]
            node = state
            while parent[node] is not None:
                prev, box = parent[node]  # type: ignore[misc]
                path.append(box)
                node = prev
            return tuple(reversed(path))
        for box in others:
            if box in state:
                continue
            nxt = state | {box}
            if nxt in parent:
                continue
            if safe(state, box):
                parent[nxt] = (state, box)
                queue.append(nxt)
    return None


def true_scene_oracle(scene: "Scene", seed: int = 0, config: "PhysicsConfig | None" = None):
    """``safe(removed, box)`` on the scene taken as ground truth (one PyBullet world).

    Every state the search reaches was reached by real pulls: after a
    collapse-free pull the world is snapshotted under its removed-set, and a
    later question about that set restores it bit-exactly. So the sequence
    `min_removals` returns is exactly a replay of pulls, like the robot's.
    Asking about a set that was never reached raises ``KeyError``. Results are
    cached; call ``.close()`` when done, ``.calls()`` counts the pulls.
    """

    sim = ShelfSim(scene, config)
    snaps = {frozenset(): sim.snapshot()}
    cache: dict[tuple[frozenset[str], str], bool] = {}

    def safe(removed: frozenset[str], box: str) -> bool:
        key = (frozenset(removed), box)
        if key not in cache:
            sim.restore(snaps[key[0]])
            res = sim.remove(box, seed=seed, stop_on_collapse=True)
            cache[key] = bool(res.ok)
            after = key[0] | {box}
            if res.ok and after not in snaps:
                snaps[after] = sim.snapshot()
        return cache[key]

    def close() -> None:
        for snap in snaps.values():
            sim.forget(snap)
        snaps.clear()
        sim.close()

    safe.close = close  # type: ignore[attr-defined]
    safe.calls = lambda: len(cache)  # type: ignore[attr-defined]
    return safe


def exhaustive_minimum(scene: "Scene", target: str, seed: int = 0,
                       config: "PhysicsConfig | None" = None,
                       max_boxes: int = MAX_BOXES) -> tuple[str, ...] | None:
    """The shortest collapse-free extraction of ``target`` on the true scene, or None.

    "Collapse-free" is `StepResult.ok` for every pull (the box came out and no
    other box passed the collapse thresholds), the benchmark's success test.
    """
    scene.require(target)
    safe = true_scene_oracle(scene, seed, config)
    try:
        return min_removals(scene.ids, target, safe, max_boxes)
    finally:
        safe.close()  # type: ignore[attr-defined]
