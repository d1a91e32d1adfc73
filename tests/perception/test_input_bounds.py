"""Bad input that used to get through (issue 30): outputs onto devices and FIFOs, box ids that are
not printable text, implausible physical quantities, images whose header claims a huge size.
Every one is refused in one line naming the file and the field, before anything is allocated."""
from __future__ import annotations

import json
import os
import stat
import struct
import zlib
from pathlib import Path

import numpy as np
import pytest

from shelfpick.console.cli import main
from shelfpick.perception.capture import MAX_IMAGE_BYTES, read_depth, read_rgb
from shelfpick.perception.errors import FormatError, PerceptionError
from shelfpick.perception.scene import Camera, Scene, output_path, write_json

GOOD_SCENE = {"format": "shelfpick.scene/1", "shelf": {"width": 1.0, "depth": 0.3, "height": 1.6},
              "boxes": [{"id": "a", "size": [0.2, 0.2, 0.2], "position": [-0.2, 0.12, 0.1]}]}
GOOD_CAMERA = {"format": "shelfpick.camera/1", "width": 64, "height": 48, "fx": 60.0, "fy": 60.0, "cx": 32.0,
               "cy": 24.0, "depth_scale": 0.001,
               "pose": {"position": [0.0, -1.04, 0.8], "orientation": [0.7071068, -0.7071068, 0.0, 0.0]}}


def one_line(capsys) -> str:
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1, err
    assert "Traceback" not in err[0]
    return err[0]


def scene_with(tmp_path: Path, **box) -> Path:
    doc = json.loads(json.dumps(GOOD_SCENE))
    doc["boxes"][0].update(box)
    p = tmp_path / "scene.json"
    p.write_text(json.dumps(doc))
    return p


# ---------------------------------------------------------------- item 4: outputs onto special files
def test_a_fifo_as_out_is_refused_and_stays_a_fifo(tmp_path: Path, capsys) -> None:
    fifo = tmp_path / "plan.fifo"
    os.mkfifo(fifo)
    rc = main(["plan", str(scene_with(tmp_path)), "--task", "clear", "--samples", "1", "--out", str(fifo)])
    assert rc == 2
    line = one_line(capsys)
    assert str(fifo) in line and "--out" in line and "a FIFO, not a regular file" in line
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_a_char_device_is_refused_without_writing_to_it() -> None:
    before = os.lstat("/dev/null")
    with pytest.raises(FormatError, match="a device, not a regular file"):
        output_path("/dev/null", "--out")          # judged only: nothing is written, nothing renamed
    after = os.lstat("/dev/null")
    assert stat.S_ISCHR(after.st_mode) and after.st_ino == before.st_ino


def test_folders_and_symlinks_to_special_files_are_refused(tmp_path: Path) -> None:
    fifo = tmp_path / "f"
    os.mkfifo(fifo)
    (tmp_path / "to_fifo").symlink_to(fifo)
    (tmp_path / "to_null").symlink_to("/dev/null")
    (tmp_path / "dangling").symlink_to(tmp_path / "nothing")
    for name, says in (("to_fifo", "a FIFO"), ("to_null", "a device"), (".", "a folder"), ("dangling", "symlink")):
        with pytest.raises(FormatError, match=says):
            write_json(tmp_path / name, {"x": 1}, "--out")
    assert (tmp_path / "to_fifo").is_symlink() and (tmp_path / "to_null").is_symlink()
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)


def test_a_regular_file_or_a_link_to_one_is_replaced_atomically(tmp_path: Path) -> None:
    target = tmp_path / "real.json"
    target.write_text("old")
    (tmp_path / "link.json").symlink_to(target)
    write_json(tmp_path / "link.json", {"x": 1})
    assert (tmp_path / "link.json").is_symlink() and json.loads(target.read_text()) == {"x": 1}
    write_json(tmp_path / "new" / "n.json", {"y": 2})
    assert json.loads((tmp_path / "new" / "n.json").read_text()) == {"y": 2}


def test_perceive_refuses_a_fifo_overlay_before_any_work(tmp_path: Path, capsys) -> None:
    corpus = Path(__file__).resolve().parents[1] / "fuzz_corpus" / "good"
    fifo = tmp_path / "overlay.png"
    os.mkfifo(fifo)
    rc = main(["perceive", "--rgb", str(corpus / "rgb.png"), "--depth", str(corpus / "depth.png"), "--camera",
               str(corpus / "camera.json"), "--out", str(tmp_path / "s.json"), "--overlay", str(fifo)])
    assert rc == 2 and "--overlay: a FIFO" in one_line(capsys)
    assert not (tmp_path / "s.json").exists()


# ---------------------------------------------------------------- box ids
@pytest.mark.parametrize("bad", ["a\nb", "\x1b[31mred\x1b[0m", "nul\x00", "\udc80", " lead", "x" * 65, "tab\t",
                                 "\u202eevil"])
def test_box_ids_must_be_printable_text(tmp_path: Path, capsys, bad: str) -> None:
    p = scene_with(tmp_path, id=bad)
    rc = main(["plan", str(p), "--task", "clear", "--samples", "1"])
    assert rc == 2
    line = one_line(capsys)
    assert "boxes[0].id: a box id is 1-64 printable characters" in line
    assert line.isprintable() and "\x1b" not in line       # shown escaped, never raw


def test_printable_unicode_and_markup_ids_still_load(tmp_path: Path) -> None:
    for good in ("b0", "Karton ä-1", "<img src=x>", "x" * 64):
        assert Scene.load(scene_with(tmp_path, id=good)).ids == (good,)


def test_plan_files_and_masks_json_take_the_same_rule(tmp_path: Path) -> None:
    from shelfpick.perception.capture import read_labels
    from shelfpick.planning.plan import Plan

    plan = {"format": "shelfpick.plan/1", "task": "extract", "target": "a\x1b", "planner": "heuristic",
            "sequence": ["a\x1b"], "safe": True}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    with pytest.raises(FormatError, match=r"sequence\[0\]: a box id"):
        Plan.load(tmp_path / "plan.json")
    (tmp_path / "masks.json").write_text(json.dumps({"1": "b\n2"}))
    with pytest.raises(FormatError, match="masks.json: 1: a box id"):
        read_labels(tmp_path / "masks.json")


# ---------------------------------------------------------------- implausible quantities
@pytest.mark.parametrize("change, field", [
    ({"shelf": {"width": 1e300, "depth": 0.3, "height": 1.6}}, "shelf.width: must be within [0.05, 20] m"),
    ({"box": {"size": [1e-12, 0.2, 0.2]}}, "boxes[id=a].size[0]: must be within [0.01, 5] m"),
    ({"box": {"mass": 1e9}}, "boxes[id=a].mass: must be within"),
])
def test_implausible_scenes_are_refused(tmp_path: Path, change: dict, field: str) -> None:
    doc = json.loads(json.dumps(GOOD_SCENE))
    if "shelf" in change:
        doc["shelf"] = change["shelf"]
    else:
        doc["boxes"][0].update(change["box"])
    with pytest.raises(FormatError, match=field.replace("[", r"\[").replace("]", r"\]")):
        Scene.from_json(doc, "s.json")


@pytest.mark.parametrize("key, value, says", [
    ("position", [0.0, -1e300, 0.8], "pose.position[1]: must be within [-50, 50] m"),
    ("fx", 1e300, "fx: must be within"),
    ("width", 30000, "width: must be at most 12000 px"),
    ("depth_scale", 1e6, "depth_scale: must be within"),
])
def test_implausible_cameras_are_refused(key: str, value, says: str) -> None:
    doc = json.loads(json.dumps(GOOD_CAMERA))
    (doc["pose"] if key == "position" else doc)[key] = value
    with pytest.raises(FormatError, match=says.replace("[", r"\[").replace("]", r"\]")):
        Camera.from_json(doc, "camera.json")


# ---------------------------------------------------------------- item 7: images bounded by their header
def huge_png(path: Path, w: int, h: int) -> Path:
    """A few hundred bytes claiming w x h pixels: a valid header, one short compressed row."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 4096))
                     + chunk(b"IEND", b""))
    return path


def test_a_30000_square_png_is_refused_from_its_header(tmp_path: Path) -> None:
    p = huge_png(tmp_path / "rgb.png", 30000, 30000)
    assert p.stat().st_size < 1000
    with pytest.raises(PerceptionError, match="rgb.png: image"):
        read_rgb(p)
    with pytest.raises(PerceptionError, match="depth.png: image"):
        read_depth(huge_png(tmp_path / "depth.png", 20000, 2500), 0.001)   # 50 million: over the 40 million


def test_a_npy_header_claiming_a_huge_array_is_refused(tmp_path: Path) -> None:
    p = tmp_path / "depth.npy"
    header = "{'descr': '<f4', 'fortran_order': False, 'shape': (100000, 100000), }"
    header += " " * (63 - (10 + len(header)) % 64) + "\n"
    p.write_bytes(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + b"\0" * 64)
    with pytest.raises(PerceptionError, match="depth.npy: depth array is 100000x100000"):
        read_depth(p, 0.001)


def test_an_image_that_is_a_device_or_too_big_is_refused_before_reading(tmp_path: Path) -> None:
    (tmp_path / "rgb.png").symlink_to("/dev/zero")
    with pytest.raises(PerceptionError, match="not a regular file"):
        read_rgb(tmp_path / "rgb.png")
    big = tmp_path / "big.png"
    with open(big, "wb") as f:                      # sparse: no disk used
        f.truncate(MAX_IMAGE_BYTES + 1)
    with pytest.raises(PerceptionError, match=f"{MAX_IMAGE_BYTES + 1} bytes"):
        read_rgb(big)


def test_an_ordinary_image_still_reads(tmp_path: Path) -> None:
    import cv2

    img = np.zeros((48, 64, 3), np.uint8)
    img[10:20, 10:30] = (200, 100, 50)
    cv2.imwrite(str(tmp_path / "rgb.png"), img)
    assert read_rgb(tmp_path / "rgb.png").shape == (48, 64, 3)


def test_the_schemas_say_the_same_bounds_and_id_rule() -> None:
    jsonschema = pytest.importorskip("jsonschema")
    from referencing import Registry, Resource

    root = Path(__file__).resolve().parents[2] / "docs" / "schemas"
    docs = {n: json.loads((root / f"{n}.schema.json").read_text()) for n in ("scene", "plan", "camera")}
    registry = Registry().with_resources((d["$id"], Resource.from_contents(d)) for d in docs.values())
    check = {n: jsonschema.Draft202012Validator(d, registry=registry) for n, d in docs.items()}

    def scene(**box) -> dict:
        doc = json.loads(json.dumps(GOOD_SCENE))
        doc["boxes"][0].update(box)
        return doc

    assert check["scene"].is_valid(scene(id="<img src=x>")) and check["scene"].is_valid(scene(id="Karton ä-1"))
    for bad in ("a\nb", "\x1b[31m", "nul\x00", " lead", "trail ", "x" * 65):
        assert not check["scene"].is_valid(scene(id=bad)), bad
    assert not check["scene"].is_valid(scene(size=[1e-12, 0.2, 0.2]))
    assert not check["scene"].is_valid({**GOOD_SCENE, "shelf": {"width": 1e300, "depth": 0.3, "height": 1.6}})
    far = json.loads(json.dumps(GOOD_CAMERA))
    far["pose"]["position"] = [0, -1e300, 0]
    assert check["camera"].is_valid(GOOD_CAMERA) and not check["camera"].is_valid(far)
    plan = {"format": "shelfpick.plan/1", "task": "clear", "target": None, "planner": "physics",
            "sequence": ["a", "b\x1b"]}
    assert not check["plan"].is_valid(plan)
    assert check["plan"].is_valid({**plan, "sequence": ["a", "b"]})
