"""Photo-like wall frames for the learned segmenter's second training round
(`perception/train_scenes.py`): flush walls of one print, labelled one face per carton."""
from __future__ import annotations

from itertools import pairwise

import numpy as np
import pytest

pytest.importorskip("pybullet")


def test_wall_scene_is_flush_cartons_inside_the_shelf_sharing_prints():
    from perception.train_scenes import wall_scene

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
    from perception.train_scenes import wall_example

    rgb, labels = wall_example(30804)
    assert rgb.dtype == np.uint8 and rgb.shape[:2] == labels.shape
    ids = [k for k in np.unique(labels) if k]
    assert len(ids) >= 10                                    # a wall: many faces, each its own label
    rgb2, labels2 = wall_example(30804)
    assert np.array_equal(rgb, rgb2) and np.array_equal(labels, labels2)


def test_training_refuses_wall_seeds_of_the_first_round():
    from perception.train_learned import main

    with pytest.raises(SystemExit) as e:
        main(["--walls", "1", "--wall-seed", "30500", "--frames", "1"])
    assert e.value.code == 2
