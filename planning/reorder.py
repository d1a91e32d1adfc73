"""Take an unsafe extraction plan's blockers from the top down when that is predicted better.

Algorithm 1 pulls blockers in the order the failed pulls moved them: the first
collapser first. Where a blocker still carries another box, that order pulls a
box from under a load; the plans that held on the independent judge where ours
collapsed were often the same boxes taken highest first. This pass asks the
oracle about one other order of the same boxes: the blockers highest top first
(`heuristic.height_key`, the order a person clears a stack in), then the
target. It is kept unless the physics predicts it a lower chance that no step
collapses by more than one standard error of that chance over the sample worlds:
ten worlds cannot tell 0.7 from 0.6, and where they cannot, the order that does
not pull a box from under a load is the better bet (on the independent judge it
held where the search's order collapsed; docs/planners.md). That benefit of the
doubt is not given where a box of the plan leans more than `LEAN_DEG`: on a leaning
pile the highest top is a box resting against the others, not the top of a stack
(there top first is kept only when predicted better). A safe plan is left as
it is; the pass never adds or drops a box.
"""
from __future__ import annotations

from typing import Callable

from shelfpick.perception.scene import Scene, quat_to_matrix
from shelfpick.planning.extract import Oracle, SearchResult
from shelfpick.planning.geometry3 import lean_deg
from shelfpick.planning.heuristic import height_key
from shelfpick.planning.resolution import prefer, resolution
from shelfpick.planning.shorten import Screen, alternative

LEAN_DEG = 5.0   # a box leaning more than this rests against something: its top is no stack's top


def top_first(scene: Scene, sequence: tuple[str, ...]) -> tuple[str, ...]:
    """The blockers of `sequence` (all but its last box) highest first, then the target."""
    boxes = {b.id: b for b in scene.boxes}
    return tuple(sorted(sequence[:-1], key=lambda i: height_key(boxes[i]))) + sequence[-1:]


def reorder_extraction(result: SearchResult, scene: Scene, oracle: Oracle, risk: float = 0.0, *,
                       screen: Screen | None = None, worlds: int | None = None,
                       passed: Callable[[], bool] = lambda: False) -> SearchResult:
    """`result` with its blockers taken top first, unless the `worlds` sample worlds predict that
    order likelier to collapse by more than they can resolve (`resolution`; without `worlds`:
    only when it is predicted better, as also where a box of the plan is `leaning`). `screen`
    bounds each step as in `shorten`; `passed()` True skips."""
    seq = tuple(result.sequence)
    if len(seq) < 3 or result.safe or passed():
        return result
    cand = top_first(scene, seq)
    if cand == seq:
        return result
    start = next(k for k, (a, b) in enumerate(zip(seq, cand)) if a != b)
    slack = 0.0 if leaning(scene, seq) else resolution(result.success_prob, worlds)
    return prefer(alternative(result, cand, start, oracle, risk, screen, slack), result, slack)


def leaning(scene: Scene, ids: tuple[str, ...]) -> bool:
    """Whether any of `ids` leans more than `LEAN_DEG` (a turn about the vertical is not a lean)."""
    return any(lean_deg(quat_to_matrix(scene.box(i).orientation)) > LEAN_DEG for i in ids)
