"""`shelfpick calibrate`: a printed ChArUco board at the shelf gives the camera's pose."""
from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from shelfpick.perception.calibrate import BoardPlacement, BoardSpec, board_in_view, calibrate
from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.geometry import matrix_to_quat
from shelfpick.perception.render import default_camera
from shelfpick.perception.scene import Camera, quat_to_matrix


def _errors(got: Camera, true: Camera) -> tuple[float, float]:
    r = np.asarray(quat_to_matrix(got.orientation)).T @ np.asarray(quat_to_matrix(true.orientation))
    ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(r) - 1) / 2))))
    return float(np.linalg.norm(np.subtract(got.position, true.position))), ang


def _top_down() -> Camera:
    """A camera 1.1 m above a pallet, the neura way: shelf +y is down, shelf z along the image's up."""
    # camera z (optical axis) = shelf +y (down into the pallet), camera y (image down) = shelf -z
    rot = np.stack([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]], axis=1)
    return Camera(640, 480, 607.6, 606.7, 315.7, 249.5, 0.001, (0.05, -1.1, 0.4), matrix_to_quat(rot))


@pytest.mark.parametrize("camera,placement", [
    (default_camera(), BoardPlacement("front", (-0.24, 0.0, 0.62))),
    (default_camera(), BoardPlacement("floor", (-0.24, 0.36, 0.0))),
    (_top_down(), BoardPlacement("front", (-0.2, 0.0, 0.55))),
])
def test_board_in_a_rendered_image_gives_the_camera_pose(camera, placement):
    rng = np.random.default_rng(0)
    bg = np.clip(rng.normal(110, 20, (480, 640, 3)), 0, 255).astype(np.uint8)
    img = board_in_view(camera, BoardSpec(), placement, bg)
    img = np.clip(img.astype(np.float32) + rng.normal(0, 2.0, img.shape), 0, 255).astype(np.uint8)
    wrong = Camera(640, 480, 607.6, 606.7, 315.7, 249.5, 0.001, (0.0, -2.0, 0.3), (1.0, 0.0, 0.0, 0.0))
    cal = calibrate(img, wrong, BoardSpec(), placement)
    pos_err, ang_err = _errors(cal.camera, camera)
    assert cal.corners >= 10 and cal.rms_px < 0.5
    assert pos_err < 0.01 and ang_err < 1.0, (pos_err, ang_err)
    # the placement matters: the board taken for one on the floor puts the camera elsewhere
    other = BoardPlacement("floor" if placement.plane == "front" else "front", placement.origin)
    assert _errors(calibrate(img, wrong, BoardSpec(), other).camera, camera)[1] > 45


def test_cli_writes_a_camera_file_and_refuses_a_blank_image(tmp_path, capsys):
    from shelfpick.console.cli import main

    cam = default_camera()
    placement = BoardPlacement("front", (-0.24, 0.0, 0.62))
    img = board_in_view(cam, BoardSpec(), placement, np.full((480, 640, 3), 120, np.uint8))
    cv2.imwrite(str(tmp_path / "board.png"), img[:, :, ::-1])
    Camera(640, 480, cam.fx, cam.fy, cam.cx, cam.cy, 0.001, (0, 0, 0), (1.0, 0, 0, 0)).save(tmp_path / "intr.json")
    rc = main(["calibrate", "--rgb", str(tmp_path / "board.png"), "--camera", str(tmp_path / "intr.json"),
               "--origin", "-0.24", "0", "0.62", "--out", str(tmp_path / "cam.json")])
    assert rc == 0, capsys.readouterr().err
    pos_err, ang_err = _errors(Camera.load(tmp_path / "cam.json"), cam)
    assert pos_err < 0.01 and ang_err < 1.0
    cv2.imwrite(str(tmp_path / "blank.png"), np.full((480, 640, 3), 120, np.uint8))
    rc = main(["calibrate", "--rgb", str(tmp_path / "blank.png"), "--camera", str(tmp_path / "intr.json"),
               "--out", str(tmp_path / "cam2.json")])
    err = capsys.readouterr().err
    assert rc == 2 and "found 0 ChArUco corners" in err and "blank.png" in err
    assert not (tmp_path / "cam2.json").exists()
    assert main(["calibrate", "--write-board", str(tmp_path / "print.png")]) == 0
    assert cv2.imread(str(tmp_path / "print.png")).shape[:2] == (700, 900)


def test_bad_board_spec_is_one_line():
    with pytest.raises(PerceptionError, match="dictionary 'DICT_NOPE'"):
        BoardSpec(dictionary="DICT_NOPE").board()
    with pytest.raises(PerceptionError, match="marker side"):
        BoardSpec(square=0.04, marker=0.05).board()
