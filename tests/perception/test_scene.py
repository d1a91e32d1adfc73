"""The scene and camera documents: round trips and the errors users see."""
from __future__ import annotations

import json
import math

import pytest

from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Box, Camera, Scene, Shelf, yaw_quat


def scene_doc(**box_overrides):
    box = {"id": "b0", "size": [0.31, 0.25, 0.23], "position": [-0.30, 0.13, 0.115],
           "orientation": [1.0, 0.0, 0.0, 0.0]}
    box.update(box_overrides)
    return {"format": "shelfpick.scene/1", "shelf": {"width": 1.0, "depth": 0.30, "height": 1.60},
            "boxes": [box]}


def test_round_trip_keeps_everything(tmp_path):
    doc = scene_doc(mass=2.5, depth_known=False, mask_label=3, colour="brown")
    doc["source"] = {"kind": "test"}
    doc["camera"] = Camera(640, 480, 600.0, 600.0, 320.0, 240.0).to_json()
    scene = Scene.from_json(doc, "mem")
    path = tmp_path / "s.json"
    scene.save(path)
    again = Scene.load(path)
    assert again == scene
    assert again.boxes[0].extra == {"colour": "brown"}
    assert again.to_json() == scene.to_json()
    assert again.camera.width == 640


def test_a_settled_shelf_saved_and_loaded_is_the_shelf_in_memory_bit_for_bit(tmp_path):
    """A shelf that came out of the physics (quaternions unit to the last digits, not exactly)
    reads back equal, so the console's capture and `shelfpick plan` on its file plan alike; a
    quaternion written rounded is still made unit."""
    from shelfpick.planning.shelves import generate

    truth = generate("structured", 1878384624, 12)
    path = tmp_path / "truth.json"
    truth.save(path)
    assert Scene.load(path) == truth
    rounded = Scene.from_json(scene_doc(orientation=[0.7071, 0.0, 0.0, 0.7071]), "mem")
    assert math.isclose(sum(c * c for c in rounded.boxes[0].orientation), 1.0, abs_tol=1e-15)


def test_front_face_kept_when_depth_changes():
    b = Box("b", (0.3, 0.2, 0.2), (0.0, 0.12, 0.1), yaw_quat(0.3))
    deeper = b.with_depth(0.28)
    assert deeper.size[1] == pytest.approx(0.28)
    for a, c in zip(b.front_center, deeper.front_center):
        assert a == pytest.approx(c)
    hidden = Scene(Shelf(), (b,)).hide_depths(0.1)
    assert hidden.boxes[0].depth_known is False
    assert hidden.boxes[0].front_center[1] == pytest.approx(b.front_center[1])


@pytest.mark.parametrize("override, field", [
    ({"size": [0.3, float("nan"), 0.2]}, "size[1]"),
    ({"size": [0.3, 0.0, 0.2]}, "size[1]"),
    ({"size": [0.3, 0.2]}, "size"),
    ({"position": "here"}, "position"),
    ({"orientation": [0, 0, 0, 0]}, "orientation"),
    ({"orientation": [2, 0, 0, 0]}, "orientation"),
    ({"mass": -1}, "mass"),
    ({"id": ""}, "id"),
    ({"position": [2.0, 0.13, 0.115]}, "position"),
    ({"position": [0.0, 0.5, 0.115]}, "position"),
])
def test_bad_box_fields_are_named(override, field):
    with pytest.raises(FormatError) as err:
        Scene.from_json(scene_doc(**override), "shelf.json")
    msg = str(err.value)
    assert msg.startswith("shelf.json: ")
    assert field in msg


def test_missing_and_duplicated_keys():
    doc = scene_doc()
    del doc["boxes"][0]["size"]
    with pytest.raises(FormatError, match=r"boxes\[id=b0\]\.size: missing required key"):
        Scene.from_json(doc, "f")
    doc = scene_doc()
    doc["boxes"].append(dict(doc["boxes"][0], position=[0.3, 0.13, 0.115]))
    with pytest.raises(FormatError, match="duplicated box id 'b0'"):
        Scene.from_json(doc, "f")
    with pytest.raises(FormatError, match="format"):
        Scene.from_json(dict(scene_doc(), format="other/1"), "f")


def test_malformed_and_missing_files(tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("{ not json")
    with pytest.raises(FormatError, match=r"bad\.json: malformed JSON at line 1"):
        Scene.load(bad)
    with pytest.raises(FormatError, match="file not found"):
        Scene.load(tmp_path / "nope.json")


def test_unknown_target_lists_ids():
    scene = Scene.from_json(scene_doc(), "f")
    with pytest.raises(FormatError, match="unknown box id 'zz'; the scene has b0"):
        scene.require("zz", "f")


def test_camera_errors_and_example():
    example = {"format": "shelfpick.camera/1", "width": 640, "height": 480, "fx": 607.6, "fy": 606.7,
               "cx": 315.7, "cy": 249.5, "depth_scale": 0.001,
               "pose": {"position": [0.0, -1.04, 0.80], "orientation": [0.7071068, -0.7071068, 0.0, 0.0]}}
    cam = Camera.from_json(json.loads(json.dumps(example)), "cam.json")
    assert cam.fx == pytest.approx(607.6)
    assert math.isclose(sum(c * c for c in cam.orientation), 1.0)
    with pytest.raises(FormatError, match="cam.json: width"):
        Camera.from_json(dict(example, width=0), "cam.json")
    with pytest.raises(FormatError, match="pose: missing required key"):
        Camera.from_json({k: v for k, v in example.items() if k != "pose"}, "cam.json")
