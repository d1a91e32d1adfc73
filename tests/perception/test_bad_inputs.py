"""`shelfpick perceive` on bad and odd inputs: each gives a one-line error naming the file, the
field and the value (exit 2), or a sane scene (exit 0) -- never a traceback or an absurd scene.
Inputs are drawn with the tiny ray caster (`synth_frames.cast`) at 320x240 unless said."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from shelfpick.console.cli import main
from shelfpick.perception.scene import Camera, Scene, Shelf
from synth_frames import SMALL_CAMERA, box, cast

SCENE = Scene(Shelf(), (box("a", -0.25, 0, 0.30, 0.25), box("b", 0.15, 0, 0.25, 0.20, front=0.06)))


@pytest.fixture(scope="module")
def cap(tmp_path_factory) -> Path:
    d = tmp_path_factory.mktemp("bad") / "cap"
    cast(SCENE, noise=0.001).save(d)
    return d


def perceive(capsys, rgb, camera, depth=None, *extra, out=None) -> tuple[int, str, Path]:
    out = Path(out or Path(camera).parent / "out_scene.json")
    argv = ["perceive", "--rgb", str(rgb), "--camera", str(camera), "--out", str(out), "--segmenter", "depth"]
    argv += ["--depth", str(depth)] if depth is not None else []
    rc = main(argv + [str(e) for e in extra])
    return rc, capsys.readouterr().err, out


def refused(capsys, *args, **kw) -> str:
    rc, err, _ = perceive(capsys, *args, **kw)
    assert rc == 2, err
    lines = [ln for ln in err.strip().splitlines() if ln.strip()]
    assert len(lines) == 1, err
    return lines[0]


def sane(capsys, *args, n: int | None = 2, **kw) -> tuple[Scene, str]:
    """Exit 0, a scene that loads again, every box inside the shelf; `n`: the box count."""
    rc, err, out = perceive(capsys, *args, **kw)
    assert rc == 0, err
    scene = Scene.load(out)
    if n is not None:
        assert len(scene.boxes) == n, err
    for b in scene.boxes:
        assert abs(b.position[0]) < scene.shelf.width / 2 and 0 < b.position[2] < scene.shelf.height
    if n == 2:
        widths = sorted(round(b.size[0], 2) for b in scene.boxes)
        assert abs(widths[0] - 0.25) < 0.02 and abs(widths[1] - 0.30) < 0.02, widths
    return scene, err


def camera_file(cap: Path, name: str, **change) -> Path:
    doc = json.loads((cap / "camera.json").read_text())
    for k, v in change.items():
        (doc["pose"] if k in ("position", "orientation") else doc)[k] = v
    p = cap.parent / f"{name}.json"
    p.write_text(json.dumps(doc))
    return p


def depth_units(cap: Path) -> np.ndarray:
    return cv2.imread(str(cap / "depth.png"), cv2.IMREAD_UNCHANGED)


# ---------------------------------------------------------------- the list
def test_missing_and_unreadable_files(cap, capsys):
    assert "nope.png: RGB image not found" in refused(capsys, cap / "nope.png", cap / "camera.json")
    assert "nope.png: depth image not found" in refused(capsys, cap / "rgb.png", cap / "camera.json", cap / "nope.png")
    assert "nope.json: file not found" in refused(capsys, cap / "rgb.png", cap.parent / "nope.json")
    (cap.parent / "text.png").write_text("hello")
    assert "text.png: not a readable image" in refused(capsys, cap.parent / "text.png", cap / "camera.json")
    (cap.parent / "broken.json").write_text("{not json")
    assert "broken.json: malformed JSON" in refused(capsys, cap / "rgb.png", cap.parent / "broken.json")


def test_rgb_and_depth_of_different_sizes(cap, capsys):
    cv2.imwrite(str(cap.parent / "half.png"), depth_units(cap)[:120, :160])
    assert "half.png: depth image is 160x120 but the RGB image is 320x240" in \
        refused(capsys, cap / "rgb.png", cap / "camera.json", cap.parent / "half.png")


@pytest.mark.parametrize("kind", ["zeros", "nan"])
def test_depth_all_zero_or_nan(cap, capsys, kind):
    p = cap.parent / f"d_{kind}.npy"
    np.save(p, np.zeros((240, 320)) if kind == "zeros" else np.full((240, 320), np.nan))
    assert f"d_{kind}.npy: depth image has no valid pixel" in refused(capsys, cap / "rgb.png", cap / "camera.json", p)


@pytest.mark.parametrize("field, value, says", [("fx", 3.0, "fx=3 gives a 177.9 deg field of view"),
                                                ("cx", 900, "cx=900 lies outside"),
                                                ("width", 640, "camera is 640x240 but the RGB image is 320x240")])
def test_intrinsics_that_do_not_match_the_image(cap, capsys, field, value, says):
    p = camera_file(cap, f"cam_{field}", **{field: value})
    line = refused(capsys, cap / "rgb.png", p, cap / "depth.png")
    assert says in line and f"cam_{field}.json" in line


def test_weights_that_do_not_load(cap, capsys):
    (cap.parent / "fake.pt").write_bytes(b"not a torch checkpoint")
    assert "fake.pt: cannot load YOLO segmentation weights" in \
        refused(capsys, cap / "rgb.png", cap / "camera.json", cap / "depth.png", "--segmenter", "yolo",
                "--weights", cap.parent / "fake.pt")
    # not a .pt at all: ultralytics raised a TypeError traceback for this one
    assert "camera.json: --weights must be a YOLO11n-seg .pt checkpoint" in \
        refused(capsys, cap / "rgb.png", cap / "camera.json", cap / "depth.png", "--weights", cap / "camera.json")


def test_no_boxes_is_an_empty_scene_and_a_warning(tmp_path, capsys):
    cast(Scene(Shelf(), ()), noise=0.001).save(tmp_path / "empty")
    scene, err = sane(capsys, tmp_path / "empty/rgb.png", tmp_path / "empty/camera.json", tmp_path / "empty/depth.png",
                      n=0)
    assert "no boxes found" in err


# ---------------------------------------------------------------- odd files
@pytest.mark.parametrize("name", ["rgb.png", "rgb.jpg", "depth.png"])
def test_a_truncated_png_or_jpeg_is_refused(cap, capsys, name):
    src = cap / name
    if name == "rgb.jpg":
        cv2.imwrite(str(src), cv2.imread(str(cap / "rgb.png")))
    data = src.read_bytes()
    cut = cap.parent / f"cut_{name}"
    cut.write_bytes(data[: len(data) // 2])
    # a truncated JPEG used to decode silently with a grey lower half (only a libjpeg warning)
    args = (cut, cap / "camera.json", cap / "depth.png") if name != "depth.png" else \
        (cap / "rgb.png", cap / "camera.json", cut)
    line = refused(capsys, *args)
    assert f"cut_{name}: truncated {'JPEG' if name.endswith('jpg') else 'PNG'}" in line


def test_a_whole_jpeg_with_data_after_its_end_marker_is_read(cap, capsys):
    """Cameras and editors append data after the end-of-image marker (a real RCAN photo carries
    9.6 KB of it); such a file is whole and must not be taken for a truncated one."""
    ok, buf = cv2.imencode(".jpg", cv2.imread(str(cap / "rgb.png")))
    assert ok
    tailed = cap.parent / "tailed.jpg"
    tailed.write_bytes(buf.tobytes() + b"\x00TRAILER" * 500)
    from shelfpick.perception.capture import read_rgb

    assert read_rgb(tailed).shape == cv2.imread(str(cap / "rgb.png")).shape


@pytest.mark.parametrize("kind", ["rgb16", "rgba", "grey"])
def test_16_bit_rgba_and_grey_images_are_converted(cap, capsys, kind):
    bgr = cv2.imread(str(cap / "rgb.png"))
    img = {"rgb16": bgr.astype(np.uint16) * 257,
           "rgba": np.dstack([bgr, np.full(bgr.shape[:2], 255, np.uint8)]),
           "grey": cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)}[kind]
    cv2.imwrite(str(cap.parent / f"{kind}.png"), img)
    sane(capsys, cap.parent / f"{kind}.png", cap / "camera.json", cap / "depth.png")


def test_a_tiny_image_gives_an_empty_scene_not_a_crash(tmp_path, capsys):
    cam = Camera(32, 24, 30.0, 30.0, 16.0, 12.0, 0.001, SMALL_CAMERA.position, SMALL_CAMERA.orientation)
    cast(SCENE, cam, noise=0.001).save(tmp_path / "tiny")
    sane(capsys, tmp_path / "tiny/rgb.png", tmp_path / "tiny/camera.json", tmp_path / "tiny/depth.png", n=None)


@pytest.mark.slow
def test_a_large_1920x1080_image_with_a_matching_camera(tmp_path, capsys):
    cam = Camera(1920, 1080, 1300.0, 1300.0, 960.0, 540.0, 0.001, SMALL_CAMERA.position, SMALL_CAMERA.orientation)
    cast(SCENE, cam, noise=0.001).save(tmp_path / "big")
    sane(capsys, tmp_path / "big/rgb.png", tmp_path / "big/camera.json", tmp_path / "big/depth.png")


# ---------------------------------------------------------------- odd depth
def test_float64_npy_depth_in_metres(cap, capsys):
    np.save(cap.parent / "d64.npy", depth_units(cap).astype(np.float64) / 1000)
    sane(capsys, cap / "rgb.png", cap / "camera.json", cap.parent / "d64.npy")


def test_inf_and_scattered_holes_are_no_data(cap, capsys):
    """3% inf pixels, and 10% scattered zero pixels in a PNG: both used to matter (each hole cut
    the surface like a depth jump; 10% holes left an empty scene)."""
    rng = np.random.default_rng(0)
    d = depth_units(cap).astype(np.float64) / 1000
    d[rng.random(d.shape) < 0.03] = np.inf
    np.save(cap.parent / "dinf.npy", d)
    sane(capsys, cap / "rgb.png", cap / "camera.json", cap.parent / "dinf.npy")
    u = depth_units(cap)
    u[rng.random(u.shape) < 0.10] = 0
    cv2.imwrite(str(cap.parent / "holes.png"), u)
    sane(capsys, cap / "rgb.png", cap / "camera.json", cap.parent / "holes.png")


def test_negative_depth_is_refused(cap, capsys):
    d = depth_units(cap).astype(np.float64) / 1000
    d[:, :100] *= -1
    np.save(cap.parent / "dneg.npy", d)
    line = refused(capsys, cap / "rgb.png", cap / "camera.json", cap.parent / "dneg.npy")
    assert "dneg.npy: 24000 negative depth values (min -1.3" in line


@pytest.mark.parametrize("kind, says", [("metres_png", "median depth 0.001 m with depth_scale 0.001"),
                                        ("mm_npy", "median depth 1.29e+03 m with depth_scale 0.001"),
                                        ("uint8_png", "depth image must be uint16"),
                                        ("str_npy", "depth array must be numbers")])
def test_depth_in_the_wrong_units_or_type(cap, capsys, kind, says):
    u = depth_units(cap)
    p = cap.parent / f"d_{kind}.{kind.split('_')[1]}"
    if kind == "metres_png":           # metres stored in a uint16 PNG: all 0-2
        cv2.imwrite(str(p), np.round(u / 1000).astype(np.uint16))
    elif kind == "mm_npy":             # millimetres in a float .npy (float is read as metres)
        np.save(p, u.astype(np.float32))
    elif kind == "uint8_png":
        cv2.imwrite(str(p), (u // 10).astype(np.uint8))
    else:
        np.save(p, np.full((240, 320), "1.0"))
    line = refused(capsys, cap / "rgb.png", cap / "camera.json", p)
    assert p.name in line and says in line


def test_a_camera_depth_scale_that_does_not_fit_the_depth(cap, capsys):
    p = camera_file(cap, "cam_scale", depth_scale=1.0)
    line = refused(capsys, cap / "rgb.png", p, cap / "depth.png")
    assert "depth.png: median depth 1.29e+03 m with depth_scale 1 (" in line and "cam_scale.json" in line


# ---------------------------------------------------------------- odd cameras and scenes
def test_a_non_orthonormal_rotation_is_refused(cap, capsys):
    """The camera format holds the rotation as a quaternion; one that is not unit length would
    be a scaled, non-orthonormal rotation matrix."""
    p = camera_file(cap, "cam_q", orientation=[0.9, -0.7, 0.0, 0.0])
    line = refused(capsys, cap / "rgb.png", p, cap / "depth.png")
    assert "cam_q.json: pose.orientation: quaternion is not unit length (|q|=1.1402)" in line


def test_a_camera_looking_away_from_the_shelf_warns(cap, capsys):
    # the same pixels with a pose turned 180 deg: the depth now lies behind the shelf front
    p = camera_file(cap, "cam_away", orientation=[0.7071067811865476, 0.7071067811865476, 0.0, 0.0])
    _, err = sane(capsys, cap / "rgb.png", p, cap / "depth.png", n=0)
    assert "the camera looks 180 deg away from the shelf's depth axis" in err


def test_boxes_flush_with_the_back_wall(tmp_path, capsys):
    """Boxes 2 cm deep whose fronts are 2 cm before the back wall are still boxes; boxes whose
    fronts are within the wall margin are the wall: an empty scene and a warning, nothing absurd."""
    near = Scene(Shelf(), (box("a", -0.25, 0, 0.30, 0.25, front=0.28, d=0.02),
                           box("b", 0.15, 0, 0.25, 0.20, front=0.28, d=0.02)))
    cast(near, noise=0.001).save(tmp_path / "near")
    sane(capsys, tmp_path / "near/rgb.png", tmp_path / "near/camera.json", tmp_path / "near/depth.png")
    flush = Scene(Shelf(), (box("a", -0.25, 0, 0.30, 0.25, front=0.296, d=0.004),
                            box("b", 0.15, 0, 0.25, 0.20, front=0.296, d=0.004)))
    cast(flush, noise=0.001).save(tmp_path / "flush")
    _, err = sane(capsys, tmp_path / "flush/rgb.png", tmp_path / "flush/camera.json", tmp_path / "flush/depth.png",
                  n=0)
    assert "no boxes found" in err


# ---------------------------------------------------------------- odd options and outputs
@pytest.mark.parametrize("extra, says", [(["--shelf", "0", "0.3", "1.6"], "--shelf: sizes and distances must be finite and > 0 m, got 0 0.3 1.6"),
                                         (["--shelf", "nan", "0.3", "1.6"], "--shelf: sizes and distances must be finite"),
                                         (["--box-size", "nan", "0.2"], "--box-size: sizes and distances must be finite"),
                                         (["--front-distance", "-1"], "--front-distance: sizes and distances")])
def test_option_values_that_are_no_sizes(cap, capsys, extra, says):
    # --shelf 0 0.3 1.6 used to write a scene that could not be loaded again
    assert says in refused(capsys, cap / "rgb.png", cap / "camera.json", cap / "depth.png", *extra)


def test_outputs_that_cannot_be_written(cap, capsys, tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    line = refused(capsys, cap / "rgb.png", cap / "camera.json", cap / "depth.png", out=blocker / "s.json")
    assert "a_file/s.json: cannot write the scene" in line
    line = refused(capsys, cap / "rgb.png", cap / "camera.json", cap / "depth.png", "--overlay", tmp_path / "ov.txt")
    assert "ov.txt: cannot write the overlay image" in line
    line = refused(capsys, cap / "rgb.png", cap / "camera.json", cap / "depth.png", "--masks", tmp_path / "m.jpg")
    assert "m.jpg: --masks must be a .png file" in line


@pytest.mark.parametrize("w, h", [(1, 1), (2, 2)])
def test_an_image_of_a_few_pixels_is_refused(tmp_path, capsys, w, h):
    """1x1 and 2x2 images used to end in a numpy broadcast traceback inside the segmenter."""
    cv2.imwrite(str(tmp_path / "rgb.png"), np.full((h, w, 3), 128, np.uint8))
    cv2.imwrite(str(tmp_path / "depth.png"), np.full((h, w), 1000, np.uint16))
    doc = Camera(w, h, float(w), float(w), w / 2, h / 2).to_json()
    (tmp_path / "camera.json").write_text(json.dumps(doc))
    line = refused(capsys, tmp_path / "rgb.png", tmp_path / "camera.json", tmp_path / "depth.png")
    assert f"rgb.png: image is {w}x{h} px; perception needs at least 16 px a side" in line


@pytest.mark.parametrize("units, noise", [(500, 0), (1040, 0), (1300, 0), (1040, 3)])
def test_a_flat_depth_is_refused_not_turned_into_boxes(cap, capsys, units, noise):
    """A constant (or near-constant, +-3 mm) depth has no shelf in it: segmenting the RGB's edges on
    one plane gave 12 boxes with exit 0 (issue 10); at 0.5 m the faces were also outside the shelf."""
    rng = np.random.default_rng(0)
    d = np.full((240, 320), units, np.float64) + rng.integers(-noise, noise + 1, (240, 320))
    d[::17, ::13] = 0  # a few holes do not make structure
    cv2.imwrite(str(cap.parent / "flat.png"), d.astype(np.uint16))
    line = refused(capsys, cap / "rgb.png", cap / "camera.json", cap.parent / "flat.png")
    assert "flat.png: depth is flat" in line and f"of {units / 1000:.3f} m" in line


def test_masks_json_with_bad_keys_or_values(cap, capsys, tmp_path):
    """masks.json beside a rendered capture: a non-integer key was a ValueError traceback."""
    import shutil

    d = tmp_path / "cap"
    shutil.copytree(cap, d)
    masks = json.loads((d / "masks.json").read_text())
    for doc, says in [({"x": "a"}, "masks.json: 'x': expected a mask label (an integer 1-65535), got 'x'"),
                      ({"1.5": "a"}, "got '1.5'"), ({"0": "a"}, "got '0'"), ({"99999": "a"}, "got '99999'"),
                      ({"1": 7}, "masks.json: 1: expected a box id (a non-empty string), got 7"),
                      ([1, 2], "masks.json: expected an object of mask label -> box id, got list")]:
        (d / "masks.json").write_text(json.dumps(doc))
        assert says in refused(capsys, d / "rgb.png", d / "camera.json", d / "depth.png")
    (d / "masks.json").write_text(json.dumps(masks))
    cv2.imwrite(str(d / "masks.png"), np.zeros((10, 10), np.uint16))
    assert "masks.png: mask image must be one channel of 320x240 px, got shape (10, 10)" in \
        refused(capsys, d / "rgb.png", d / "camera.json", d / "depth.png")


@pytest.mark.parametrize("which", ["rgb", "depth"])
def test_an_empty_file_is_refused(cap, capsys, which):
    (cap.parent / "empty.png").write_bytes(b"")
    args = (cap.parent / "empty.png", cap / "camera.json", cap / "depth.png") if which == "rgb" else \
        (cap / "rgb.png", cap / "camera.json", cap.parent / "empty.png")
    assert "empty.png: empty file (0 bytes)" in refused(capsys, *args)


def test_65535_in_a_uint16_depth_png_is_no_data(cap, capsys):
    """The OAK-D convention (shared/realdata/simod...): 65535 = no return. Mostly 65535 is then
    'no valid pixel' rather than a depth 65 m away."""
    u = depth_units(cap)
    u[:, :] = 65535
    cv2.imwrite(str(cap.parent / "sat.png"), u)
    assert "sat.png: depth image has no valid pixel" in refused(capsys, cap / "rgb.png", cap / "camera.json",
                                                                   cap.parent / "sat.png")
    u = depth_units(cap)
    u[np.random.default_rng(2).random(u.shape) < 0.05] = 65535
    cv2.imwrite(str(cap.parent / "sat5.png"), u)
    sane(capsys, cap / "rgb.png", cap / "camera.json", cap.parent / "sat5.png")


def test_an_rgb_image_turned_90_degrees_says_so(cap, capsys):
    cv2.imwrite(str(cap.parent / "turned.png"), cv2.rotate(cv2.imread(str(cap / "rgb.png")), cv2.ROTATE_90_CLOCKWISE))
    line = refused(capsys, cap.parent / "turned.png", cap / "camera.json", cap / "depth.png")
    assert "camera.json: camera is 320x240 but the RGB image is 240x320 (turned 90 deg" in line
