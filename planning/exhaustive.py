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
from typing import TYPE_CHECKING, Callable, Iterable

if TYPE_CHECKING:  # pragma: no cover
    from perception.scene import Scene
    from planning.physics import PhysicsConfig

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

    The state "``removed`` gone" is rebuilt inside a rollback by taking those
    boxes away without a pull (the search only reaches states whose every pull
    was collapse-free, so nothing else moved on the way); then ``box`` is
    pulled like the robot would. Results are cached. Call ``.close()`` when done.
    """
    from planning.sim import ShelfSim

    sim = ShelfSim(scene, config)
    cache: dict[tuple[frozenset[str], str], bool] = {}

    def safe(removed: frozenset[str], box: str) -> bool:
        key = (frozenset(removed), box)
        if key not in cache:
            with sim.rollback():
                for other in sorted(removed):
                    sim.delete(other)
                res = sim.remove(box, seed=seed)
            cache[key] = bool(res.extracted and not res.collapsed and not res.collided)
        return cache[key]

    safe.close = sim.close  # type: ignore[attr-defined]
    safe.calls = lambda: len(cache)  # type: ignore[attr-defined]
    return safe


def exhaustive_minimum(scene: "Scene", target: str, seed: int = 0,
                       config: "PhysicsConfig | None" = None,
                       max_boxes: int = MAX_BOXES) -> tuple[str, ...] | None:
    """The shortest collapse-free extraction of ``target`` on the true scene, or None.

    The candidate found with deleted boxes is replayed with real pulls
    (``execute_plan``); the answer is returned only when that replay holds too.
    """
    scene.require(target)
    safe = true_scene_oracle(scene, seed, config)
    try:
        seq = min_removals(scene.ids, target, safe, max_boxes)
    finally:
        safe.close()  # type: ignore[attr-defined]
    if seq is None:
        return None
    from planning.execute import execute_plan

    ex = execute_plan(scene, seq, seed=seed, config=config)
    return seq if ex.ok else None
