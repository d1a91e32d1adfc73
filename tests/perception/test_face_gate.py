"""The depth gate on an RGB segmenter's instances (`perception.face_gate`), on depth images
built in code: planes seen by the default camera, masks drawn by hand."""
from __future__ import annotations

import dataclasses

import numpy as np

from shelfpick.perception.face_gate import GateConfig, dominant_plane, keep_faces
from shelfpick.perception.geometry import pixel_rays, pose_matrix
from shelfpick.perception.render import default_camera
from shelfpick.perception.scene import Shelf

SHELF = Shelf(width=1.0, depth=0.30, height=1.60)


def _camera():
    """The default camera at a quarter of its resolution (160x120): quick, same view."""
    c = default_camera()
    return dataclasses.replace(c, width=160, height=120, fx=c.fx / 4, fy=c.fy / 4,
                               cx=(c.cx + 0.5) / 4 - 0.5, cy=(c.cy + 0.5) / 4 - 0.5)


def _plane_depth(camera, normal, offset: float) -> np.ndarray:
    """HxW camera z-depth of the shelf-frame plane normal . p = offset (0 where it is behind)."""
    vs, us = np.mgrid[0:camera.height, 0:camera.width]
    rot, t = pose_matrix(camera)
    rays = pixel_rays(camera, us, vs) @ rot.T                 # shelf-frame direction per unit z
    n = np.asarray(normal, float)
    d = (offset - t @ n) / (rays @ n)
    return np.where(d > 0, d, 0.0).astype(np.float32)


def _box_mask(shape, rows: slice, cols: slice) -> np.ndarray:
    m = np.zeros(shape, bool)
    m[rows, cols] = True
    return m


def test_front_faces_stay_the_wall_and_the_floor_behind_it_go():
    cam = _camera()
    wall = _plane_depth(cam, (0, 1, 0), SHELF.depth)         # the back wall
    face = _plane_depth(cam, (0, 1, 0), 0.05)                # a box front 5 cm into the shelf
    beyond = _plane_depth(cam, (0, 1, 0), SHELF.depth + 0.4)  # the floor seen past a pallet
    depth = wall.copy()
    front = _box_mask(depth.shape, slice(40, 80), slice(20, 60))
    behind = _box_mask(depth.shape, slice(40, 80), slice(100, 140))
    on_wall = _box_mask(depth.shape, slice(90, 110), slice(60, 100))
    depth[front] = face[front]
    depth[behind] = beyond[behind]
    kept = keep_faces([front, behind, on_wall], depth, cam, SHELF)
    assert len(kept) == 1 and kept[0] is front
    # the same instances with the gate's inside test off (min_inside 0) all stay: it is that test
    loose = keep_faces([front, behind, on_wall], depth, cam, SHELF, GateConfig(min_inside=0.0))
    assert len(loose) == 3


def test_a_surface_that_does_not_face_the_camera_goes():
    cam = _camera()
    depth = _plane_depth(cam, (0, 1, 0), SHELF.depth)
    n = np.array([2.0, 1.0, 0.0]) / np.sqrt(5.0)             # turned 63 deg from shelf +y
    side = _plane_depth(cam, n, float(n @ [0.0, 0.15, 0.0]))
    rot, t = pose_matrix(cam)
    vs, us = np.mgrid[0:cam.height, 0:cam.width]
    pts = t + (pixel_rays(cam, us, vs) @ rot.T) * side[..., None]
    m = (side > 0) & (pts[..., 1] > 0.03) & (pts[..., 1] < SHELF.depth - 0.05) & (pts[..., 2] > 0.1) \
        & (pts[..., 2] < 0.6)
    assert m.sum() > 200
    depth[m] = side[m]
    assert keep_faces([m], depth, cam, SHELF) == []
    assert len(keep_faces([m], depth, cam, SHELF, GateConfig(facing_cos=0.0))) == 1


def test_a_face_spilling_onto_the_wall_stays_and_one_without_depth_is_left_alone():
    cam = _camera()
    depth = _plane_depth(cam, (0, 1, 0), SHELF.depth)
    face = _plane_depth(cam, (0, 1, 0), 0.05)
    inst = _box_mask(depth.shape, slice(40, 80), slice(40, 100))
    body = _box_mask(depth.shape, slice(40, 80), slice(40, 88))   # 80 % front face, 20 % wall
    depth[body] = face[body]
    blank = _box_mask(depth.shape, slice(95, 110), slice(10, 30))
    depth[blank] = 0.0
    assert len(keep_faces([inst, blank], depth, cam, SHELF)) == 2


def test_the_dominant_plane_ignores_a_minority_of_other_points():
    rng = np.random.default_rng(1)
    flat = np.c_[rng.uniform(-0.2, 0.2, 700), rng.normal(0, 0.002, 700), rng.uniform(0, 0.3, 700)]
    side = np.c_[np.full(300, 0.2), rng.uniform(0, 0.3, 300), rng.uniform(0, 0.3, 300)]
    normal, share = dominant_plane(np.vstack([flat, side]), 0.012, 100, np.random.default_rng(0))
    assert abs(normal[1]) > 0.99 and 0.65 < share < 0.75
    # least squares over all points would tilt it: the test that it is not least squares
    allp = np.vstack([flat, side])
    ls = np.linalg.svd(allp - allp.mean(axis=0), full_matrices=False)[2][2]
    assert abs(ls[1]) < 0.99


def test_the_learned_segmenter_gates_rgbd_instances_but_not_photos(monkeypatch):
    from shelfpick.perception.segment_learned import LearnedConfig, LearnedSegmenter

    cam = _camera()
    depth = _plane_depth(cam, (0, 1, 0), SHELF.depth + 0.4)    # beyond the back wall ...
    face = _plane_depth(cam, (0, 1, 0), 0.05)
    depth[40:80, 20:60] = face[40:80, 20:60]                   # ... but for one box front
    prob = np.zeros((3, 30, 40), np.float32)
    prob[0] = 1.0
    for c0 in (5, 25):                                         # two carton-like blocks (1/4 scale)
        prob[:, 10:20, c0:c0 + 10] = 0.0
        prob[1, 10:20, c0:c0 + 10] = 1.0
    seg = object.__new__(LearnedSegmenter)                     # no network: its maps are given
    seg.config, seg.model = LearnedConfig(snap_iou=0.0), None
    monkeypatch.setattr(LearnedSegmenter, "probabilities", lambda self, rgb: prob)
    rgb = np.zeros((cam.height, cam.width, 3), np.uint8)
    bound = seg.bind(cam, SHELF)
    kept = bound.segment(rgb, depth)
    assert len(kept) == 1 and kept[0][60, 40] and not kept[0][60, 120]
    off = bound.with_config(dataclasses.replace(bound.config, depth_gate=False))
    assert len(off.segment(rgb, depth)) == 2
    assert len(bound.rgb_only().segment(rgb, depth)) == 2


def test_a_face_the_network_never_saw_is_added_from_the_depth(monkeypatch):
    """Issue 14: boxes leaning 40+ deg (never in the training renders) got no instance at all;
    a depth-and-edge mask lying where the network has no instance is added when the depth makes
    it a planar front face in the shelf. Fails with `add_unseen` 0 (the network's mask alone)."""
    from shelfpick.perception.segment_learned import LearnedConfig, LearnedSegmenter

    cam = _camera()
    depth = _plane_depth(cam, (0, 1, 0), SHELF.depth)          # the back wall ...
    face = _plane_depth(cam, (0, 1, 0), 0.05)
    seen, unseen = (_box_mask(depth.shape, slice(40, 80), slice(c, c + 40)) for c in (20, 100))
    for m in (seen, unseen):                                   # ... and two box fronts
        depth[m] = face[m]
    prob = np.zeros((3, 30, 40), np.float32)
    prob[0] = 1.0
    prob[:, 10:20, 5:15] = 0.0                                 # the network sees the left one only
    prob[1, 10:20, 5:15] = 1.0
    seg = object.__new__(LearnedSegmenter)                     # no network: its maps are given
    seg.config, seg.model, seg.threads = LearnedConfig(), None, None
    monkeypatch.setattr(LearnedSegmenter, "probabilities", lambda self, rgb: prob)
    rgb = np.zeros((cam.height, cam.width, 3), np.uint8)
    bound = seg.bind(cam, SHELF)
    out = bound.segment(rgb, depth)
    assert len(out) == 2 and out[0][60, 40] and out[1][60, 120]
    assert (out[1] & unseen).sum() >= 0.95 * out[1].sum() and out[1].sum() >= 0.5 * unseen.sum()
    off = bound.with_config(dataclasses.replace(bound.config, add_unseen=0.0))
    assert len(off.segment(rgb, depth)) == 1
    # where the network had an instance, even one the depth gate then dropped (mostly beyond the
    # back wall, the face a quarter of it), nothing is added: the network saw the region
    prob[:, 5:28, 22:40] = 0.0
    prob[1, 5:28, 22:40] = 1.0
    big = _box_mask(depth.shape, slice(20, 112), slice(88, 160))
    depth[big & ~unseen] = _plane_depth(cam, (0, 1, 0), SHELF.depth + 0.4)[big & ~unseen]
    assert len(bound.segment(rgb, depth)) == 1


def test_only_planar_facing_masks_in_the_shelf_are_plausible_faces():
    from shelfpick.perception.face_gate import plausible_faces

    cam = _camera()
    depth = _plane_depth(cam, (0, 1, 0), SHELF.depth)
    flat = _box_mask(depth.shape, slice(40, 80), slice(20, 60))
    depth[flat] = _plane_depth(cam, (0, 1, 0), 0.05)[flat]
    steps = _box_mask(depth.shape, slice(40, 80), slice(90, 150))   # three 5 cm steps: no plane
    for k, y in enumerate((0.04, 0.10, 0.16)):
        part = _box_mask(depth.shape, slice(40, 80), slice(90 + 20 * k, 110 + 20 * k))
        depth[part] = _plane_depth(cam, (0, 1, 0), y)[part]
    on_wall = _box_mask(depth.shape, slice(90, 110), slice(60, 100))
    kept = plausible_faces([flat, steps, on_wall], depth, cam, SHELF)
    assert len(kept) == 1 and kept[0] is flat
