"""The console's look after a robot step: a new frame, perceived, compared with the predicted shelf."""
from __future__ import annotations

import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any, Mapping, NamedTuple

from shelfpick.perception.scene import Box, Scene, Shelf

if TYPE_CHECKING:
    from shelfpick.console.sources import Frame, Source
    from shelfpick.console.workflow.verify import Tolerance, Verification
    from shelfpick.perception.pipeline import Perception
    from shelfpick.perception.segment import Segmenter


class Look(NamedTuple):
    """One look after a step: the verdict, the frame and its perception (None when there was no
    frame or perception failed) and the shelf the plan predicted (None: no prediction)."""

    verification: Verification
    frame: Frame | None
    perception: Perception | None
    predicted: Scene | None


def look_again(source: Source, world: Scene | None, step: int, box: str, predicted: Scene | None,
               shelf: Shelf | None, segmenter: Segmenter | None = None, tolerance: Tolerance | None = None,
               perceive_options: Mapping[str, Any] | None = None, removed: Box | None = None,
               confirm: bool = True) -> Look:
    """The console's look after `step`: a new frame, perceived, compared with the `predicted` shelf.

    Returns a `Look` (verification, frame, perception, predicted). A
    camera or perception fault, no new frame or no prediction is a verdict
    that holds (`unavailable`), never an exception. `shelf`: the installation's
    shelf when the frame knows no truth; `removed`: the box the step took out, as
    perceived (a box it hid is not new). A difference is looked at a second time
    (`confirm`): a box that moved is still moved in the next frame, a face that
    perception cut differently in one frame mostly is not; when the second look
    finds the shelf as predicted the step passes, the first look's summary kept
    in `unconfirmed`; when it cannot be made the first verdict stands (hold).
    benchmarks/closed_loop.py times and scores exactly this function.
    """
    first = _look_once(source, world, step, box, predicted, shelf, segmenter, tolerance, perceive_options,
                       removed, 0)
    v = first.verification
    if not confirm or v.within or v.unavailable:
        return first
    second = _look_once(source, world, step, box, predicted, shelf, segmenter, tolerance, perceive_options,
                        removed, 1)
    v2 = second.verification
    timing = {k: v.timing.get(k, 0.0) + v2.timing.get(k, 0.0) for k in v.timing}
    if v2.within:
        return second._replace(verification=replace(v2, timing=timing, unconfirmed=v.summary()))
    if v2.unavailable:
        return first._replace(verification=replace(v, timing=timing))
    return second._replace(verification=replace(v2, timing=timing))


def _look_once(source: Source, world: Scene | None, step: int, box: str, predicted: Scene | None,
               shelf: Shelf | None, segmenter: Segmenter | None, tolerance: Tolerance | None,
               perceive_options: Mapping[str, Any] | None, removed: Box | None, attempt: int) -> Look:
    """One frame, perceived and compared."""
    from shelfpick.console.workflow.verify import Tolerance, compare, unavailable
    from shelfpick.perception.pipeline import perceive

    tol = tolerance or Tolerance()
    t0 = time.perf_counter()
    try:
        frame = source.look_again(world, step, attempt) if attempt else source.look_again(world, step)
    except Exception as exc:  # noqa: BLE001 - a camera fault holds the robot, it is not a crash
        return Look(unavailable(step, box, f"camera: {exc}", tol), None, None, predicted)
    if frame is None:
        return Look(unavailable(step, box, "the source has no new frame since the last capture", tol), None, None,
                    predicted)
    t1 = time.perf_counter()
    try:
        opts = {k: v for k, v in (perceive_options or {}).items() if k != "shelf"}
        perception = perceive(frame.capture, segmenter,
                              shelf=frame.truth.shelf if frame.truth is not None else shelf, **opts)
    except Exception as exc:  # noqa: BLE001
        return Look(unavailable(step, box, f"perception: {exc}", tol), frame, None, predicted)
    t2 = time.perf_counter()
    if predicted is None:
        v = unavailable(step, box, "the plan has no predicted shelf for this step", tol)
    else:
        v = compare(predicted, perception.scene, step, box, tol, removed)
    t3 = time.perf_counter()
    return Look(replace(v, timing={"capture_s": t1 - t0, "perceive_s": t2 - t1, "compare_s": t3 - t2}), frame,
                perception, predicted)


def as_planned(observed: Scene, v: Verification) -> Scene:
    """The shelf a look saw, with the plan's ids on the boxes it matched to the plan's (the ids the
    operator knows); a box it matched to none keeps the look's id, marked `?`."""
    back = {o: p for p, o in v.observed_of().items()}
    return replace(observed, boxes=tuple(replace(b, id=back.get(b.id, f"{b.id}?")) for b in observed.boxes))


__all__ = ["Look", "look_again", "as_planned"]
