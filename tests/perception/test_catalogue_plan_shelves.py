"""Round 11 catalogue rules on the planning shelves where they were found (rendered with
PyBullet, seen by benchmarks/perceive_plan.py's framing camera): every true box is perceived
as one box, each true box's visible front face mostly in one perceived mask. The rules repair
the depth-and-edge segmenter's pieces, so it is named here (since issue 14 `auto` takes the
learned segmenter for RGB-D, which does not cut these faces into those pieces)."""
from __future__ import annotations

import numpy as np
import pytest

from benchmarks import perceive_plan as pp


def _perceived_per_true_box(seed: int) -> tuple[dict[str, list[str]], list[str]]:
    from shelfpick.perception.evaluation.truth import front_face_masks
    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.render import render
    from shelfpick.perception.segment_depth import DepthEdgeSegmenter
    from shelfpick.planning.shelves import generate

    truth = generate("unstructured", seed, 10)
    cap = render(truth, pp.framing_camera(truth), seed=seed)
    res = perceive(cap, DepthEdgeSegmenter(), truth.shelf)
    ids = pp.map_ids(res.masks, res.scene, front_face_masks(truth, cap))
    per: dict[str, list[str]] = {b.id: [] for b in truth.boxes}
    for pid, tid in ids.items():
        per[tid].append(pid)
    return per, list(res.adjustments)


@pytest.mark.parametrize("seed, rule", [
    # a 50x17 face cut by a dark tape cross at 1.9 m, one quarter a 20x20 face by chance
    pytest.param(5009, "joined a 30x14 cm piece"),
    # four one-colour 50x17 faces stacked with offsets: one 70x68 cm mask
    pytest.param(5003, "staircase", marks=pytest.mark.slow),
    # a face's part below its tape band merged with the yawed box under it, 1.6 cm nearer
    pytest.param(5035, "off its rest", marks=pytest.mark.slow),
])
def test_each_true_box_is_one_perceived_box(seed, rule):
    per, notes = _perceived_per_true_box(seed)
    assert all(len(v) == 1 for v in per.values()), (per, notes)
    assert any(rule in n for n in notes), notes


def test_band_trim_keeps_a_chance_face_within_the_pieces_band():
    from shelfpick.perception.repairs.planes import band_trim
    from shelfpick.perception.faces import measure_front
    from shelfpick.perception.scene import Scene, Shelf
    from synth_frames import COLOURS, box, cast

    scene = Scene(Shelf(), (box("low", -0.08, 0.0, 0.50, 0.17), box("up", 0.04, 0.17, 0.50, 0.17)))
    cap = cast(scene)
    low = (cap.masks == 1) & np.all(cap.rgb == np.asarray(COLOURS[0]), axis=-1)
    up = (cap.masks == 2) & np.all(cap.rgb == np.asarray(COLOURS[1]), axis=-1)
    cols = np.arange(low.shape[1])[None, :]
    rows = np.arange(low.shape[0])[:, None]
    xs, ys = np.nonzero(low)[1], np.nonzero(low)[0]
    cut = int(xs.min() + 0.6 * np.ptp(xs))
    strip = up & (rows >= ys.min() - 12) & (cols >= cut) & (cols <= xs.max())
    right = (low & (cols >= cut)) | strip
    face = measure_front(right, cap.depth, cap.camera)
    trimmed = band_trim(low & (cols < cut), right, face, cap.camera)
    assert trimmed is not None
    # the upper box's 4 cm strip goes, but for the 1 cm margin kept past the pieces' band
    assert (trimmed & strip).sum() <= 0.3 * strip.sum()
    assert (trimmed & low).sum() >= 0.97 * (right & low).sum()        # the cut face's part stays
    # nothing sticks out of the band: nothing to trim
    assert band_trim(low & (cols < cut), low & (cols >= cut), face, cap.camera) is None
