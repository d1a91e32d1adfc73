"""Unexplained matter: depth points inside the shelf that no perceived box (nor the shelf) explains."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.boxes import not_a_face
from shelfpick.perception.pipeline import perceive
from shelfpick.perception.scene import Box, Scene, Shelf
from shelfpick.perception.segment_depth import DepthEdgeSegmenter
from shelfpick.perception.unexplained import MIN_AREA_M2, describe, find_unexplained
from synth_frames import box, cast

SHELF = Shelf(1.0, 0.30, 1.60)


def _row() -> Scene:
    """Three cartons on the floor and one on the middle one (fronts at y = 0.02)."""
    return Scene(SHELF, (box("b0", -0.27, 0.0, 0.23, 0.25), box("b1", 0.0, 0.0, 0.23, 0.25),
                         box("b2", 0.27, 0.0, 0.23, 0.25), box("b3", 0.0, 0.25, 0.23, 0.25)))


def _seen(scene: Scene) -> tuple[Box, ...]:
    """The boxes as perception gives them: front faces exact, depths a placeholder."""
    return scene.hide_depths(0.25).boxes


def test_a_clean_cast_of_a_known_shelf_reports_nothing():
    scene = _row()
    cap = cast(scene, noise=0.001)
    assert find_unexplained(cap.depth, cap.camera, SHELF, _seen(scene)).regions == ()


def test_a_clean_render_of_a_known_shelf_reports_nothing():
    """The training renderer with its depth-sensor noise (holes at edges, dropouts, specular
    blobs), its shelf boards, lip and top, seen from the default camera."""
    from shelfpick.perception.render import default_camera, render

    scene = _row()
    for seed in (0, 1):
        cap = render(scene, default_camera(), seed=seed)
        found = find_unexplained(cap.depth, cap.camera, SHELF, _seen(scene))
        assert found.regions == (), describe(found.regions)
        assert not found.labels.any()


def test_a_box_missing_from_the_scene_but_in_the_depth_is_one_region_where_it_stands():
    scene = _row()
    cap = cast(scene, noise=0.001)
    found = find_unexplained(cap.depth, cap.camera, SHELF, _seen(scene.without(["b2"])))
    assert len(found.regions) == 1, describe(found.regions)
    u = found.regions[0]
    b = scene.box("b2")
    assert u.id == "u0"
    # where: its seen front spans the box's front face (less the 2 cm band the floor explains)
    assert abs((u.min[0] + u.max[0]) / 2 - b.position[0]) < 0.01
    assert abs((u.max[0] - u.min[0]) - b.size[0]) < 0.02
    assert abs(u.min[1] - b.front_y) < 0.01
    assert 0.015 < u.min[2] < 0.035 and abs(u.max[2] - 0.25) < 0.01
    # how large: about the front face the camera sees (23 x 23 cm above the floor band)
    assert 0.8 * 0.23 * 0.23 < u.area_m2 < 1.2 * 0.23 * 0.25
    assert u.pixels == int((found.labels == 1).sum()) > 1000
    # its columns cover the seen face and nothing beside it
    xs = [c[0] for c in u.columns] + [c[1] for c in u.columns]
    assert min(xs) > 0.27 - 0.115 - 0.01 and max(xs) < 0.27 + 0.115 + 0.01
    assert "1 region" in describe(found.regions) and "u0 at x=0.27" in describe(found.regions)


def test_a_box_missing_in_a_render_is_one_region_too():
    from shelfpick.perception.render import default_camera, render

    scene = _row()
    cap = render(scene, default_camera(), seed=2)
    found = find_unexplained(cap.depth, cap.camera, SHELF, _seen(scene.without(["b3"])))
    assert len(found.regions) == 1, describe(found.regions)
    u = found.regions[0]
    assert abs((u.min[0] + u.max[0]) / 2) < 0.015 and abs(u.max[0] - u.min[0] - 0.23) < 0.03
    assert abs(u.min[2] - 0.25) < 0.03 and abs(u.max[2] - 0.50) < 0.02


def test_flying_pixels_and_speckle_are_not_reported():
    """Scattered points between the camera and the back wall, a one-pixel line of them along a
    box edge and a 2 x 2 cm scrap: none of it is matter worth a region (MIN_AREA_M2)."""
    scene = _row()
    cap = cast(scene, noise=0.001)
    depth = cap.depth.copy()
    rng = np.random.default_rng(0)
    back = np.argwhere(cap.masks == 0)
    for v, u in back[rng.choice(len(back), 300, replace=False)]:
        depth[v, u] *= rng.uniform(0.75, 0.98)       # flying pixels: somewhere along the ray
    lab = cap.masks == 3                                 # b2's right edge: a line of flying pixels
    cols = np.flatnonzero(lab.any(axis=0))
    rows = np.flatnonzero(lab[:, cols[-1]])
    depth[rows, cols[-1] + 1] = depth[rows, cols[-1]] + 0.05
    depth[60:66, 30:36] = 1.10                          # a 6 x 6 px scrap, about 2 x 2 cm
    found = find_unexplained(depth, cap.camera, SHELF, _seen(scene))
    assert found.regions == (), describe(found.regions)
    assert MIN_AREA_M2 > (6 * 1.1 / 300) ** 2


def test_a_mask_refused_as_no_box_front_becomes_unexplained_matter():
    """A board on its edge on the floor (60 x 8 cm front) is no box front (a strip): perception refuses
    its mask, and before issue 31 the scene went on as if nothing stood there. The matter is still
    there, and the region says which mask it was."""
    scene = Scene(SHELF, (box("plank", -0.15, 0.0, 0.60, 0.08, d=0.03), box("other", 0.30, 0.0, 0.20, 0.20)))
    cap = cast(scene, noise=0.0005)

    class Truth:
        name = "truth"

        def segment(self, rgb, depth):
            return [cap.masks == 1, cap.masks == 2]

    res = perceive(cap, Truth(), SHELF)
    assert len(res.scene.boxes) == 1 and res.scene.boxes[0].position[0] > 0.2     # only "other" is a box
    refused = [w for w in res.warnings if w.startswith("mask ") and "cm strip)" in w]
    assert len(refused) == 1, res.warnings
    mask = refused[0].split(":")[0]
    regions = res.scene.unexplained
    assert regions is not None and len(regions) == 1, res.warnings
    u = regions[0]
    assert u.why == f"{mask} refused as no box front"
    assert abs(u.min[0] + 0.45) < 0.01 and abs(u.max[0] - 0.15) < 0.01 and abs(u.max[2] - 0.08) < 0.01
    assert any(w.startswith("1 region of matter") for w in res.warnings)
    assert res.unexplained_labels is not None and (res.unexplained_labels == 1).sum() == u.pixels
    assert res.summary()["unexplained"][0]["id"] == "u0"
    # the overlay greys and hatches the region: its pixels differ from the plain RGB there
    sel = res.unexplained_labels == 1
    assert np.abs(res.overlay[sel].astype(int) - cap.rgb[sel].astype(int)).mean() > 10
    # the plank alone, as perception measures it, is what not_a_face refuses
    assert "strip" in not_a_face(_face_of(cap.masks == 1, cap), cap.masks == 1)


def _face_of(mask, cap):
    from shelfpick.perception.faces import measure_front

    return measure_front(mask, cap.depth, cap.camera)


def test_perceive_on_a_clean_shelf_says_it_looked_and_found_nothing():
    scene = _row()
    cap = cast(scene, noise=0.001, tape=True)
    res = perceive(cap, DepthEdgeSegmenter(), SHELF)
    assert len(res.scene.boxes) == 4
    assert res.scene.unexplained == () and not res.warnings
    assert "unexplained" in res.timing
    assert Scene.from_json(res.scene.to_json()).unexplained == ()


def test_without_a_depth_image_nobody_knows_where_matter_is():
    from shelfpick.perception.capture import Capture

    cap = cast(_row())
    res = perceive(Capture(cap.rgb, None, cap.camera), DepthEdgeSegmenter(), SHELF, front_distance=1.0)
    assert res.scene.unexplained is None and res.unexplained_labels is None
    assert "unexplained" not in res.scene.to_json()


@pytest.mark.parametrize("max_pixels", [160 * 120])
def test_a_scaled_down_capture_keeps_its_regions_at_full_size(max_pixels, monkeypatch):
    from shelfpick.perception import pipeline

    monkeypatch.setattr(pipeline, "FIND_MISSED_FRONTS", False)   # b2's front would be perceived as a box
    scene = _row()
    cap = cast(scene, noise=0.001)

    class Without:
        """The truth masks less b2's."""

        name = "truth-less-b2"

        def segment(self, rgb, depth):
            import cv2

            h, w = depth.shape
            return [cv2.resize((cap.masks == k).astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST) > 0
                    for k in (1, 2, 4)]

    res = perceive(cap, Without(), SHELF, max_pixels=max_pixels)
    assert len(res.scene.unexplained) == 1
    assert res.unexplained_labels.shape == cap.depth.shape
    assert abs((res.scene.unexplained[0].min[0] + res.scene.unexplained[0].max[0]) / 2 - 0.27) < 0.02


def test_shelfpick_perceive_warns_of_the_regions_and_writes_them(tmp_path, capsys):
    """A 6 x 40 cm board standing upright beside two cartons, 8 cm behind their fronts: real
    matter that is no box front; the CLI says where and how large, and the scene file carries it."""
    from shelfpick.console.cli import main

    scene = Scene(SHELF, (box("a", -0.25, 0.0, 0.23, 0.25), box("b", 0.0, 0.0, 0.23, 0.25),
                          box("board", 0.30, 0.0, 0.06, 0.40, front=0.10)))
    cast(scene, noise=0.001).save(tmp_path / "cap")
    out = tmp_path / "scene.json"
    cap = tmp_path / "cap"
    rc = main(["perceive", "--rgb", str(cap / "rgb.png"), "--depth", str(cap / "depth.png"),
               "--camera", str(cap / "camera.json"), "--segmenter", "depth", "--out", str(out),
               "--overlay", str(tmp_path / "ov.png")])
    assert rc == 0
    said = capsys.readouterr().err.splitlines()
    warned = [m for m in said if "no perceived box explains" in m]
    assert len(warned) == 1 and "warning: 1 region of matter" in warned[0] and "u0 at x=0.30 z=0.21" in warned[0], said
    assert any("1 unexplained region ->" in m for m in said)
    doc = Scene.load(out)
    assert len(doc.boxes) == 2 and len(doc.unexplained) == 1
    u = doc.unexplained[0]
    assert abs(u.max[0] - u.min[0] - 0.06) < 0.01 and abs(u.min[1] - 0.10) < 0.01
    assert 0.015 < u.min[2] < 0.035 and abs(u.max[2] - 0.40) < 0.01


def test_a_box_on_refused_matter_stays_where_the_camera_saw_it():
    """Issue 31: a box's support was refused as no box front, and the box was then 'hung in the
    air; dropped onto the floor' into the hole. The refused matter now holds it up while the scene
    is made valid: the carton on the board stays at z 0.08-0.28, not 8 cm lower on the floor."""
    scene = Scene(SHELF, (box("plank", -0.15, 0.0, 0.60, 0.08, d=0.03), box("top", -0.15, 0.08, 0.25, 0.20, d=0.03)))
    cap = cast(scene, noise=0.0005)

    class Truth:
        name = "truth"

        def segment(self, rgb, depth):
            return [cap.masks == 1, cap.masks == 2]

    res = perceive(cap, Truth(), SHELF)
    (top,) = res.scene.boxes
    assert abs(min(c[2] for c in top.corners()) - 0.08) < 0.01, res.adjustments
    assert not any("dropped onto" in a for a in res.adjustments)
    (u,) = res.scene.unexplained
    assert u.why.endswith("refused as no box front")
    assert abs(u.min[0] + 0.45) < 0.01 and abs(u.max[0] - 0.15) < 0.01
