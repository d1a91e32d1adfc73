"""Fifth-round training frames (`perception/training/printed_shelves.py`): shelves of flush
cartons sharing one design under a hard directional light, labelled one whole face per carton."""
from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage as ndi

pytest.importorskip("pybullet")

SEEDS = range(34000, 34012)


def _same_print(a: np.ndarray, b: np.ndarray) -> bool:
    """One design up to brightness and a half turn (correlation of the pixels)."""
    fa = a.astype(np.float64).ravel()
    return max(np.corrcoef(fa, c.astype(np.float64).ravel())[0, 1] for c in (b, b[::-1, ::-1])) > 0.98


def test_frames_are_drawn_from_the_seed_alone():
    from shelfpick.perception.training.printed_shelves import printed_shelf_example

    rgb, labels = printed_shelf_example(34005)
    rgb2, labels2 = printed_shelf_example(34005)
    assert np.array_equal(rgb, rgb2) and np.array_equal(labels, labels2)
    rgb3, _ = printed_shelf_example(34006)
    assert not np.array_equal(rgb, rgb3)


def test_most_frames_print_one_design_on_every_carton_and_designs_vary():
    from shelfpick.perception.training.printed_shelves import FAMILIES, design_texture, printed_frame

    frames = [printed_frame(s) for s in range(34000, 34040)]
    shared = [f for f in frames if f.shared]
    assert len(shared) >= 28                                   # 85 % drawn
    for f in shared:
        assert len(f.textures) == len(f.scene.boxes) >= 2
        assert all(_same_print(f.textures[0], t) for t in f.textures[1:])
    mixed = [f for f in frames if not f.shared and len(f.textures) >= 4]
    assert mixed and any(not all(_same_print(f.textures[0], t) for t in f.textures[1:]) for f in mixed)
    designs = [design_texture(np.random.default_rng(s), 128, fam) for s, fam in enumerate(FAMILIES)]
    assert not any(_same_print(a, b) for i, a in enumerate(designs) for b in designs[i + 1:])


def test_the_light_is_one_hard_directional_light_with_shadows_drawn_per_frame():
    from shelfpick.perception.training.printed_shelves import printed_frame

    lights = [printed_frame(s).light for s in SEEDS]
    assert all(li["shadow"] == 1 and li["lightDiffuseCoeff"] > li["lightAmbientCoeff"] for li in lights)
    sides = {np.sign(li["lightDirection"][0]) for li in lights}
    assert sides == {-1.0, 1.0}                                # from the left and from the right


def test_labels_are_whole_front_faces_that_shadow_edges_and_prints_do_not_cut():
    from shelfpick.perception.training.printed_shelves import printed_shelf_capture, printed_shelf_example

    crossed = 0
    for seed in SEEDS:
        rgb, labels = printed_shelf_example(seed)
        plain, _ = printed_shelf_capture(seed, shadows=False)
        assert labels.max() >= 2
        ratio = (rgb.astype(np.float64).sum(axis=2) + 1) / (plain.rgb.astype(np.float64).sum(axis=2) + 1)
        for k in range(1, int(labels.max()) + 1):
            m = labels == k
            comp, n = ndi.label(m)
            assert np.bincount(comp.ravel())[1:].max() >= 0.99 * m.sum()     # one region (stray pixels aside)
            r = ratio[m]
            crossed += bool((r < 0.8).mean() > 0.1 and (r > 0.97).mean() > 0.1)
    assert crossed >= 3                  # shadow edges run across faces that stay one label each


def test_depth_is_present_on_the_faces_and_agrees_with_the_scene():
    from shelfpick.perception.training.printed_shelves import printed_shelf_capture

    cap, scene = printed_shelf_capture(34002)
    assert cap.depth is not None and cap.depth.shape == cap.shape
    faces = cap.masks > 0
    assert (cap.depth[faces] > 0).mean() > 0.9
    dist = np.linalg.norm(np.asarray(cap.camera.position)[:2] - np.array([0.0, 0.0]))
    assert 0.5 < np.median(cap.depth[faces & (cap.depth > 0)]) < dist + 0.5
    assert set(cap.labels.values()) <= {b.id for b in scene.boxes}


def test_seeds_below_the_fifth_round_range_are_refused():
    from shelfpick.perception.training.learned import main
    from shelfpick.perception.training.printed_shelves import printed_frame

    with pytest.raises(ValueError):
        printed_frame(31000)
    for argv in (["--printed", "1", "--printed-seed", "31000", "--frames", "1"],
                 ["--wall-share", "0.5", "--printed-share", "0.6", "--frames", "1"]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2


def test_crops_come_from_the_printed_shelves_for_their_share():
    from pathlib import Path

    from shelfpick.perception.training.learned import TrainConfig, _pick

    f, w, p = [Path("f")], [Path("w")], [Path("p")]
    cfg = TrainConfig(wall_share=0.25, printed_share=0.4)
    rng = np.random.default_rng(0)
    picks = [_pick(f, w, [], cfg, rng, p)[0].name for _ in range(4000)]
    share = {k: picks.count(k) / len(picks) for k in "fwp"}
    assert abs(share["p"] - 0.4) < 0.03 and abs(share["w"] - 0.25) < 0.03 and abs(share["f"] - 0.35) < 0.03
    assert {_pick(f, w, [], cfg, rng)[0].name for _ in range(200)} == {"f", "w"}   # none given: shelves
