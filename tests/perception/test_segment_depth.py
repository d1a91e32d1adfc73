"""The depth-and-edge segmenter on small ray-cast frames (no PyBullet)."""
from __future__ import annotations

import numpy as np

from shelfpick.perception.scene import Scene, Shelf
from shelfpick.perception.segment_depth import DepthEdgeSegmenter
from synth_frames import box, cast


def _match(labels: np.ndarray, truth: np.ndarray) -> dict[int, float]:
    """truth label -> best IoU of a predicted segment."""
    out = {}
    for k in np.unique(truth):
        if k == 0:
            continue
        g = truth == k
        best = 0.0
        for j in np.unique(labels[g]):
            if j == 0:
                continue
            m = labels == j
            best = max(best, (m & g).sum() / (m | g).sum())
        out[int(k)] = best
    return out


def test_boxes_at_different_depths_and_flush_neighbours_are_separated():
    scene = Scene(Shelf(), (box("a", -0.30, 0, 0.30, 0.25), box("b", 0.0, 0, 0.25, 0.20, front=0.06),
                            box("c", 0.27, 0, 0.26, 0.30), box("d", -0.30, 0.25, 0.25, 0.20)))
    cap = cast(scene, noise=0.002, tape=True)
    labels = DepthEdgeSegmenter(cap.camera, scene.shelf).segment_labels(cap.rgb, cap.depth)
    ious = _match(labels, cap.masks)
    assert labels.max() == 4
    assert min(ious.values()) > 0.65, ious       # raw segments: face only, edges trimmed
    for j in range(1, 5):                        # every segment lies on one box
        _, counts = np.unique(cap.masks[labels == j], return_counts=True)
        assert counts.max() / counts.sum() > 0.97


def test_empty_shelf_gives_no_segments():
    cap = cast(Scene(Shelf(), ()), noise=0.002)
    seg = DepthEdgeSegmenter(cap.camera, Shelf())
    assert seg.segment(cap.rgb, cap.depth) == []


def test_unbound_segmenter_still_finds_faces():
    scene = Scene(Shelf(), (box("a", -0.2, 0, 0.3, 0.3), box("b", 0.2, 0, 0.3, 0.3, front=0.08)))
    cap = cast(scene)
    masks = DepthEdgeSegmenter().segment(cap.rgb, cap.depth)
    # without the shelf it cannot drop the back wall, but both faces are there
    ious = _match(np.max([m * (i + 1) for i, m in enumerate(masks)], axis=0).astype(np.uint16), cap.masks)
    assert len(masks) >= 2 and min(ious.values()) > 0.65


def test_auto_picks_depth_segmenter_and_photo_settings(tmp_path):
    from shelfpick.perception.segment import AutoSegmenter, for_capture, load_segmenter

    assert isinstance(load_segmenter(None, "auto"), AutoSegmenter)
    # RGB-D and photos: the learned segmenter where its weights are (test_segment_learned), else the rules
    seg = AutoSegmenter(learned_weights=tmp_path / "missing.pt")
    rgbd = for_capture(seg, has_depth=True)
    photo = for_capture(seg, has_depth=False)
    assert isinstance(rgbd, DepthEdgeSegmenter) and isinstance(photo, DepthEdgeSegmenter)
    # without depth nothing geometric separates boxes: a stricter rectangle test joins pieces
    assert photo.config.rect_fill == rgbd.config.rgb_rect_fill > rgbd.config.rect_fill
    # an explicit depth segmenter is left as it is for RGB-D
    d = DepthEdgeSegmenter()
    assert for_capture(d, True) is d

