"""Photo-like wall frames for the learned segmenter's second training round
(`perception/training/scenes.py`): flush walls of one print, labelled one face per carton."""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

pytest.importorskip("pybullet")


def test_wall_scene_is_flush_cartons_inside_the_shelf_sharing_prints():
    from shelfpick.perception.training.scenes import wall_scene

    for seed in range(5):
        scene, groups = wall_scene(np.random.default_rng(seed))
        assert len(scene.boxes) == len(groups) >= 2
        s = scene.shelf
        for b in scene.boxes:
            w, d, h = b.size
            assert -s.width / 2 - 1e-6 <= b.position[0] - w / 2 and b.position[0] + w / 2 <= s.width / 2 + 1e-6
            assert b.position[2] - h / 2 >= -1e-6 and b.position[2] + h / 2 <= s.height
            assert b.position[1] - d / 2 <= 0.02 + 1e-9          # fronts flush within 2 cm
        # boxes of one row do not overlap (centres at least a width apart, up to the 3 deg turn)
        rows: dict[float, list] = {}
        for b in scene.boxes:
            rows.setdefault(round(b.position[2] - b.size[2] / 2, 4), []).append(b)
        for row in rows.values():
            xs = sorted((b.position[0], b.size[0]) for b in row)
            for (x0, w0), (x1, w1) in pairwise(xs):
                assert x1 - x0 >= (w0 + w1) / 2 - 0.03


def test_a_wall_frame_labels_each_carton_face_apart():
    from shelfpick.perception.training.scenes import wall_example

    rgb, labels = wall_example(30804)
    assert rgb.dtype == np.uint8 and rgb.shape[:2] == labels.shape
    ids = [k for k in np.unique(labels) if k]
    assert len(ids) >= 10                                    # a wall: many faces, each its own label
    rgb2, labels2 = wall_example(30804)
    assert np.array_equal(rgb, rgb2) and np.array_equal(labels, labels2)


def test_training_refuses_wall_seeds_of_the_first_round():
    from shelfpick.perception.training.learned import main

    with pytest.raises(SystemExit) as e:
        main(["--walls", "1", "--wall-seed", "30500", "--frames", "1"])
    assert e.value.code == 2


def test_a_taped_face_is_cut_into_pieces_yet_labelled_whole():
    """Fourth round: tape, stickers and shadow edges change a carton's print (more edges
    inside the face than the plain variant has) and leave the labels one face per carton."""
    import cv2

    from shelfpick.perception.training.scenes import _group_texture, _variant, taped_variant, taped_wall_example, wall_example

    rng = np.random.default_rng(5)
    tex = _group_texture(rng)
    inner = np.s_[8:-8, 8:-8]                                # inside the darkened face border
    plain = [cv2.Canny(_variant(tex, np.random.default_rng(s)), 60, 150)[inner].mean() for s in range(12)]
    taped = [cv2.Canny(taped_variant(tex, np.random.default_rng(s)), 60, 150)[inner].mean() for s in range(12)]
    assert np.mean(taped) > 1.2 * np.mean(plain)
    rgb, labels = taped_wall_example(32004)
    rgb0, labels0 = wall_example(32004)
    assert np.array_equal(labels, labels0)                   # the same wall, the same faces
    assert not np.array_equal(rgb, rgb0)
    rgb2, _ = taped_wall_example(32004)
    assert np.array_equal(rgb, rgb2)


def test_crops_are_drawn_from_each_frame_kind_by_its_share():
    from pathlib import Path

    from shelfpick.perception.training.learned import TrainConfig, _pick

    f, w, t = [Path("f")], [Path("w")], [Path("t")]
    cfg = TrainConfig(wall_share=0.25, taped_share=0.5)
    rng = np.random.default_rng(0)
    picks = [_pick(f, w, t, cfg, rng)[0].name for _ in range(4000)]
    share = {k: picks.count(k) / len(picks) for k in "fwt"}
    assert abs(share["w"] - 0.25) < 0.03 and abs(share["t"] - 0.5) < 0.03 and abs(share["f"] - 0.25) < 0.03
    assert {_pick(f, w, [], cfg, rng)[0].name for _ in range(200)} == {"f", "w"}   # no taped frames: shelves


def test_training_refuses_taped_seeds_below_their_range_and_shares_over_one():
    from shelfpick.perception.training.learned import main

    for argv in (["--taped", "1", "--taped-seed", "31000", "--frames", "1"],
                 ["--wall-share", "0.6", "--taped-share", "0.6", "--frames", "1"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
