"""The synthetic RGB-D renderer: geometry agrees with the pinhole model, masks with labels."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.capture import load_capture_dir
from shelfpick.perception.render import default_camera, project, render
from shelfpick.perception.scene import Box, Scene, Shelf


def _scene(*boxes: Box) -> Scene:
    return Scene(Shelf(), tuple(boxes))


CENTRED = Box("c", (0.20, 0.20, 0.20), (0.0, 0.11, 0.10))
SCENE3 = _scene(Box("b0", (0.31, 0.25, 0.23), (-0.30, 0.13, 0.115)),
                Box("b1", (0.20, 0.20, 0.20), (0.05, 0.11, 0.10)),
                Box("b2", (0.50, 0.17, 0.17), (0.20, 0.10, 0.23 + 0.085)))


@pytest.fixture(scope="module")
def clean3():
    return render(SCENE3, seed=1, noise=False)


def test_default_camera_is_a_d435_in_front_of_the_shelf():
    cam = default_camera()
    assert (cam.width, cam.height) == (640, 480)
    assert 590 < cam.fx < 620 and 590 < cam.fy < 620
    assert -1.1 <= cam.position[1] <= -1.0 and 0.7 <= cam.position[2] <= 0.9
    # optical axis (camera z, 3rd column of R) points into the shelf, a little down
    from shelfpick.perception.scene import quat_to_matrix
    axis = np.asarray(quat_to_matrix(cam.orientation))[:, 2]
    assert axis[1] > 0.9 and axis[2] < 0


def test_sizes_types_and_labels_match_masks(clean3):
    cap = clean3
    assert cap.rgb.shape == (480, 640, 3) and cap.rgb.dtype == np.uint8
    assert cap.depth.shape == (480, 640) and cap.depth.dtype == np.float32
    assert cap.masks.shape == (480, 640) and cap.masks.dtype == np.uint16
    assert sorted(cap.labels) == list(range(1, 4))
    assert sorted(cap.labels.values()) == ["b0", "b1", "b2"]
    assert set(np.unique(cap.masks)) == {0, 1, 2, 3}
    for label in cap.labels:
        assert (cap.masks == label).sum() > 2000   # each box is a real blob at 1 m


def test_front_face_depth_is_the_true_distance(clean3):
    cam = clean3.camera
    for label, bid in clean3.labels.items():
        box = SCENE3.require(bid)
        (u, v), = project(cam, np.array([box.front_center]))[0]
        z_true = project(cam, np.array([box.front_center]))[1][0]
        z = clean3.depth[int(round(v)), int(round(u))]
        assert clean3.masks[int(round(v)), int(round(u))] == label
        assert abs(z - z_true) < 0.002, (bid, z, z_true)


def test_projection_matches_the_intrinsics():
    """Front-face edges of a centred box fall on the pixels the Camera intrinsics predict."""
    cap = render(_scene(CENTRED), seed=2, noise=False)
    cam = cap.camera
    b = CENTRED
    fy0 = b.position[1] - b.size[1] / 2
    corners = np.array([[-0.1, fy0, 0.0], [0.1, fy0, 0.0], [-0.1, fy0, 0.2], [0.1, fy0, 0.2]])
    uv, _ = project(cam, corners)
    mask = cap.masks == 1
    row = int(round((uv[0, 1] + uv[2, 1]) / 2))          # middle of the front face
    cols = np.nonzero(mask[row])[0]
    left, right = (uv[0, 0] + uv[2, 0]) / 2, (uv[1, 0] + uv[3, 0]) / 2
    assert abs(cols.min() - left) <= 1.0 and abs(cols.max() - right) <= 1.0, (cols.min(), cols.max(), left, right)
    col = int(round((left + right) / 2))
    rows = np.nonzero(mask[:, col])[0]
    assert abs(rows.max() - uv[0, 1]) <= 1.0, (rows.max(), uv[0, 1])   # bottom edge of the front face
    assert abs(rows.min() - uv[2, 1]) <= 1.0, (rows.min(), uv[2, 1])   # top edge: the mask is the front face
    # the camera sees the box from above: the whole visible box reaches higher
    full = render(_scene(CENTRED), seed=2, noise=False, front_only=False)
    assert np.nonzero(full.masks[:, col] == 1)[0].min() < uv[2, 1] - 5


def test_same_seed_same_image_other_seed_other_looks():
    a = render(_scene(CENTRED), seed=5)
    b = render(_scene(CENTRED), seed=5)
    c = render(_scene(CENTRED), seed=6)
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.depth, b.depth)
    assert np.array_equal(a.masks, b.masks)
    assert not np.array_equal(a.rgb, c.rgb)


def test_given_textures_paint_the_boxes():
    red = np.zeros((64, 64, 3), np.uint8)
    red[..., 0] = 220
    drawn = render(_scene(CENTRED), seed=5, noise=False)
    given = render(_scene(CENTRED), seed=5, noise=False, textures=[red])
    face = given.masks == 1
    r, g, b = (given.rgb[face][:, k].astype(float).mean() for k in range(3))
    assert r > 2 * max(g, b, 1.0)                                  # the face shows the given print
    r0, g0, b0 = (drawn.rgb[face][:, k].astype(float).mean() for k in range(3))
    assert r0 < 2 * max(g0, b0)                                    # a drawn carton is not that red
    assert np.array_equal(given.masks, drawn.masks)
    with pytest.raises(ValueError, match="one per box"):
        render(_scene(CENTRED), seed=5, textures=[red, red])


def test_noise_model_grows_with_distance_and_makes_holes(clean3):
    noisy = render(SCENE3, seed=1, noise=True)
    assert np.array_equal(noisy.masks, clean3.masks)         # ground truth is not noisy
    both = (noisy.depth > 0) & (clean3.depth > 0) & (clean3.masks > 0)
    err = noisy.depth[both] - clean3.depth[both]
    assert 0.0003 < err.std() < 0.004
    holes = (noisy.depth == 0) & (clean3.depth > 0)
    assert holes.mean() > 0.001                                # edges and dropouts read 0
    # holes sit mostly on depth edges: around box outlines
    from scipy import ndimage
    edges = ndimage.binary_dilation(ndimage.sobel(clean3.depth.astype(float), 0) ** 2
                                    + ndimage.sobel(clean3.depth.astype(float), 1) ** 2 > 1e-3, iterations=2)
    assert (holes & edges).sum() > 0.5 * holes.sum()


def test_hidden_box_gets_no_label():
    front = Box("front", (0.31, 0.25, 0.23), (-0.30, 0.125, 0.115))
    hidden = Box("hidden", (0.10, 0.04, 0.10), (-0.30, 0.275, 0.05))
    cap = render(_scene(front, hidden), seed=0, noise=False)
    assert list(cap.labels.values()) == ["front"]


def test_save_and_load_round_trip(tmp_path, clean3):
    clean3.save(tmp_path)
    back = load_capture_dir(tmp_path)
    assert np.array_equal(back.rgb, clean3.rgb)
    assert np.array_equal(back.masks, clean3.masks)
    assert back.labels == clean3.labels
    valid = clean3.depth > 0
    assert np.abs(back.depth[valid] - clean3.depth[valid]).max() <= 0.0006


def test_render_command_writes_the_capture(tmp_path):
    from shelfpick.console.cli import main

    scene_path = tmp_path / "scene.json"
    SCENE3.save(scene_path)
    out = tmp_path / "cap"
    assert main(["render", str(scene_path), "--out", str(out), "--seed", "4"]) == 0
    for name in ("rgb.png", "depth.png", "camera.json", "masks.png", "masks.json"):
        assert (out / name).is_file()
    cap = load_capture_dir(out)
    assert len(cap.labels) == 3
    assert main(["render", str(tmp_path / "missing.json"), "--out", str(out)]) == 2


def test_rendering_as_a_library_keeps_stdout_clean():
    """pybullet printf()s "argv[0]=" on the first connect of a process (and its build time on
    import): a caller's stdout (the console's log, a command's JSON) must not get them. A fresh
    process, because only the first connect prints."""
    import subprocess
    import sys

    code = ("from shelfpick.perception.render import render; from shelfpick.perception.scene import Box, Scene, Shelf; "
            "render(Scene(Shelf(), (Box('a', (0.2, 0.2, 0.2), (0.0, 0.1, 0.1)),)), seed=1)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout == "", out.stdout
