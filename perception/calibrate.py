"""The camera's pose in the shelf frame from one image of a printed ChArUco board.

A shelf (or a pallet, "a shelf on its back") has no marks a camera can find its pose from, and a
pose typed by hand is the commonest reason a scene comes out empty. A ChArUco board (OpenCV's
`cv2.aruco`: a chessboard whose white squares carry ArUco markers, so a partly hidden board
still gives identified corners) is printed, stuck at a known place of the shelf, and seen once:
its corners give the board's pose in the camera (`solvePnP`), the known placement gives the
board's pose in the shelf, and the two give the camera's pose in the shelf, written as a
`shelfpick.camera/1` file (docs/cameras.md).

Board frame (OpenCV's): origin at the printed board's top-left chessboard corner, x to the
right of the print, y down the print, z into the board. Placements (`BoardPlacement`):
- `front`: standing in the shelf's front plane facing the camera, print upright
  (board x = shelf +x, board y = shelf -z, board z = shelf +y);
- `floor`: lying on the shelf floor, print read from the front, its top toward the back wall
  (board x = shelf +x, board y = shelf -y, board z = shelf -z); for a pallet seen from above
  use `front` (the pallet's top layer is the shelf's front plane).
`origin` is where the board's top-left chessboard corner lies in the shelf frame.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.geometry import matrix_to_quat, project
from shelfpick.perception.scene import Camera

PLACEMENTS: dict[str, np.ndarray] = {
    "front": np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]]),    # columns: board x, y, z in the shelf
    "floor": np.array([[1.0, 0, 0], [0, -1.0, 0], [0, 0, -1.0]]),
}
MIN_CORNERS = 6


@dataclass(frozen=True)
class BoardSpec:
    """A ChArUco board: squares across x down, square and marker sides (m), ArUco dictionary."""

    squares_x: int = 8                  # the default prints on A2 (48 x 36 cm); 10x7 of 4 cm (A3) is
    squares_y: int = 6                  # off by 1-2 cm beyond 1.2 m (docs/cameras.md)
    square: float = 0.06
    marker: float = 0.045
    dictionary: str = "DICT_5X5_100"

    def to_json(self) -> dict:
        return {"squares_x": self.squares_x, "squares_y": self.squares_y, "square": self.square,
                "marker": self.marker, "dictionary": self.dictionary}

    @classmethod
    def from_json(cls, doc: dict) -> "BoardSpec":
        return cls(int(doc["squares_x"]), int(doc["squares_y"]), float(doc["square"]), float(doc["marker"]),
                   str(doc["dictionary"]))

    def board(self):
        """The cv2.aruco.CharucoBoard; a bad spec is a PerceptionError naming the field."""
        import cv2

        if self.squares_x < 2 or self.squares_y < 2:
            raise PerceptionError(f"board: needs at least 2x2 squares, got {self.squares_x}x{self.squares_y}")
        if not (0 < self.marker < self.square):
            raise PerceptionError(f"board: marker side {self.marker:g} m must be > 0 and smaller than the "
                                  f"square side {self.square:g} m")
        code = getattr(cv2.aruco, self.dictionary, None)
        if not self.dictionary.startswith("DICT_") or not isinstance(code, int):
            raise PerceptionError(f"board: dictionary {self.dictionary!r} is not an OpenCV ArUco dictionary "
                                  "(e.g. DICT_5X5_100, DICT_4X4_50)")
        return cv2.aruco.CharucoBoard((self.squares_x, self.squares_y), self.square, self.marker,
                                      cv2.aruco.getPredefinedDictionary(code))


@dataclass(frozen=True)
class BoardPlacement:
    """Where the board is: `plane` (a key of PLACEMENTS) and its top-left corner in the shelf (m)."""

    plane: str = "front"
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def rotation(self) -> np.ndarray:
        if self.plane not in PLACEMENTS:
            raise PerceptionError(f"board placement: plane must be one of {sorted(PLACEMENTS)}, got {self.plane!r}")
        return PLACEMENTS[self.plane]


@dataclass(frozen=True)
class Calibration:
    camera: Camera                 # the given intrinsics with the recovered pose in the shelf frame
    corners: int                   # ChArUco corners used
    rms_px: float                  # reprojection error of those corners


def board_image(spec: BoardSpec, px_per_square: int = 100, margin_squares: float = 0.5) -> np.ndarray:
    """The board to print (uint8 grey): `px_per_square` pixels per square and a white margin."""
    m = int(round(margin_squares * px_per_square))
    w, h = spec.squares_x * px_per_square, spec.squares_y * px_per_square
    img = spec.board().generateImage((w + 2 * m, h + 2 * m), marginSize=m)
    return np.asarray(img, np.uint8)


def calibrate(rgb: np.ndarray, camera: Camera, spec: BoardSpec, placement: BoardPlacement,
              origin: str = "image") -> Calibration:
    """The camera's pose in the shelf frame from the board seen in `rgb` (intrinsics from
    `camera`, whose own pose is ignored; lens distortion taken as zero, as the camera file has none)."""
    import cv2

    board = spec.board()
    r_sb = placement.rotation()
    gray = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY) if rgb.ndim == 3 else rgb
    corners, ids, _, _ = cv2.aruco.CharucoDetector(board).detectBoard(gray)
    n = 0 if ids is None else len(ids)
    if n < MIN_CORNERS:
        raise PerceptionError(f"{origin}: found {n} ChArUco corners of the {spec.squares_x}x{spec.squares_y} "
                              f"{spec.dictionary} board (need >= {MIN_CORNERS}): is the board in view, lit, "
                              "and are --board and --dictionary the printed ones?")
    obj = np.asarray(board.getChessboardCorners(), np.float64)[ids.ravel()]
    img = corners.reshape(-1, 2).astype(np.float64)
    k = np.array([[camera.fx, 0, camera.cx], [0, camera.fy, camera.cy], [0, 0, 1.0]])
    dist = np.zeros(5)
    ok, rvec, tvec = cv2.solvePnP(obj, img, k, dist, flags=cv2.SOLVEPNP_SQPNP)
    if not ok:
        raise PerceptionError(f"{origin}: the board's pose could not be solved from {n} corners")
    rvec, tvec = cv2.solvePnPRefineLM(obj, img, k, dist, rvec, tvec)
    proj, _ = cv2.projectPoints(obj, rvec, tvec, k, dist)
    rms = float(np.sqrt(np.mean(np.sum((proj.reshape(-1, 2) - img) ** 2, axis=1))))
    r_cb = cv2.Rodrigues(rvec)[0]                        # board -> camera
    r_sc = r_sb @ r_cb.T                                 # camera -> shelf
    t_sc = r_sb @ (-r_cb.T @ tvec.ravel()) + np.asarray(placement.origin, np.float64)
    cam = replace(camera, position=tuple(float(v) for v in t_sc),  # type: ignore[arg-type]
                  orientation=tuple(float(v) for v in matrix_to_quat(r_sc)))  # type: ignore[arg-type]
    return Calibration(cam, n, rms)


def board_in_view(camera: Camera, spec: BoardSpec, placement: BoardPlacement, background: np.ndarray,
                  px_per_square: int = 80) -> np.ndarray:
    """A synthetic RGB image of the printed board placed as `placement`, seen by `camera` (a pinhole
    warp of the board's print onto `background`): what `calibrate` is tested on."""
    import cv2

    margin = 0.5
    print_img = board_image(spec, px_per_square, margin)
    s = spec.square / px_per_square                      # metres per print pixel
    off = margin * px_per_square
    h, w = print_img.shape
    src = np.array([[0, 0], [w, 0], [w, h], [0, h]], np.float64)
    board_xy = (src - off) * s                           # print pixel -> board frame (z = 0)
    pts = np.column_stack([board_xy, np.zeros(4)]) @ placement.rotation().T + np.asarray(placement.origin)
    uv, z = project(camera, pts)
    if np.any(z <= 0):
        raise PerceptionError("the board lies behind the camera")
    ss = 4                                               # supersampled, then averaged down (no aliasing)
    dst = (uv + 0.5) * ss - 0.5
    hmat = cv2.getPerspectiveTransform(src.astype(np.float32) - 0.5, dst.astype(np.float32))
    size = (camera.width * ss, camera.height * ss)
    warped = cv2.warpPerspective(cv2.cvtColor(print_img, cv2.COLOR_GRAY2RGB), hmat, size, flags=cv2.INTER_LINEAR)
    cover = cv2.warpPerspective(np.full(print_img.shape, 255, np.uint8), hmat, size, flags=cv2.INTER_LINEAR)
    big = cv2.resize(background, size, interpolation=cv2.INTER_NEAREST).astype(np.float32)
    a = (cover.astype(np.float32) / 255.0)[..., None]
    big = big * (1 - a) + warped.astype(np.float32) * a
    small = cv2.resize(big, (camera.width, camera.height), interpolation=cv2.INTER_AREA)
    out = np.clip(np.round(small), 0, 255).astype(np.uint8)
    return out


__all__ = ["BoardSpec", "BoardPlacement", "Calibration", "calibrate", "board_image", "board_in_view", "PLACEMENTS"]
