"""One RGB-D capture: colour, metric depth, the camera, and optional ground truth.

Files on disk follow `shelfpick render`: `rgb.png`, `depth.png` (uint16, the
camera's `depth_scale` metres per unit, 0 = no measurement), `camera.json`,
and for rendered captures `masks.png` (uint16 instance labels) and
`masks.json` (label -> box id). Loading checks what a user can get wrong and
names the file: unreadable images, RGB and depth of different sizes, a camera
whose size does not match, a depth map with no valid pixel.
"""
from __future__ import annotations

import io
import os
import re
import stat
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np

from shelfpick.perception.errors import FormatError, PerceptionError
from shelfpick.perception.scene import MAX_IMAGE_PIXELS, MAX_IMAGE_SIDE, Camera, check_id, read_json, write_json


@dataclass(frozen=True, eq=False)
class Capture:
    rgb: np.ndarray                      # HxWx3 uint8
    depth: np.ndarray | None             # HxW float32 metres, 0 = no data; None = no depth sensor
    camera: Camera
    masks: np.ndarray | None = None      # HxW uint16 ground-truth instance labels (rendered only)
    labels: Mapping[int, str] = field(default_factory=dict)  # mask label -> box id

    def __post_init__(self) -> None:
        validate(self.rgb, self.depth, self.camera)

    @property
    def shape(self) -> tuple[int, int]:
        return self.rgb.shape[:2]

    def save(self, out_dir: str | Path) -> dict[str, Path]:
        """Write rgb.png, depth.png, camera.json (+ masks.png, masks.json)."""
        import cv2

        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        paths = {"rgb": d / "rgb.png", "camera": d / "camera.json"}
        cv2.imwrite(str(paths["rgb"]), cv2.cvtColor(self.rgb, cv2.COLOR_RGB2BGR))
        if self.depth is not None:
            paths["depth"] = d / "depth.png"
            units = np.round(np.nan_to_num(self.depth, nan=0.0) / self.camera.depth_scale)
            cv2.imwrite(str(paths["depth"]), np.clip(units, 0, 65535).astype(np.uint16))
        self.camera.save(paths["camera"])
        if self.masks is not None:
            paths["masks"] = d / "masks.png"
            paths["masks_json"] = d / "masks.json"
            cv2.imwrite(str(paths["masks"]), self.masks.astype(np.uint16))
            write_json(paths["masks_json"], {str(k): v for k, v in sorted(self.labels.items())})
        return paths


MIN_SIDE_PX = 16      # smaller images have no room for the segmenter's 7 px normal stencil


def validate(rgb: np.ndarray, depth: np.ndarray | None, camera: Camera, origin: str = "",
             camera_origin: str = "") -> None:
    """`origin`: the file named for image problems; `camera_origin`: for a camera of another size."""
    where = f"{origin}: " if origin else ""
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.dtype != np.uint8:
        raise PerceptionError(f"{where}RGB image must be HxWx3 uint8, got shape {rgb.shape} {rgb.dtype}")
    h, w = rgb.shape[:2]
    if min(h, w) < MIN_SIDE_PX:
        raise PerceptionError(f"{where}image is {w}x{h} px; perception needs at least {MIN_SIDE_PX} px a side")
    if (camera.width, camera.height) != (w, h):
        cam_where = f"{camera_origin}: " if camera_origin else where
        turned = " (turned 90 deg: a portrait photo or an EXIF orientation tag, which OpenCV applies?)" \
            if (camera.width, camera.height) == (h, w) else ""
        raise PerceptionError(f"{cam_where}camera is {camera.width}x{camera.height} but the RGB image is "
                              f"{w}x{h}{turned}")
    if depth is not None:
        if depth.shape != (h, w):
            raise PerceptionError(f"{where}depth image is {depth.shape[1]}x{depth.shape[0]} "
                                  f"but the RGB image is {w}x{h}")
        valid = np.isfinite(depth) & (depth > 0)
        if not valid.any():
            raise PerceptionError(f"{where}depth image has no valid pixel (all zero or NaN)")


def _jpeg_complete(data: bytes) -> bool:
    """Whether a JPEG that does not END with its end-of-image marker still holds a whole image:
    cameras and editors append data after the marker (a real RCAN photo carries 9.6 KB), and an
    embedded EXIF thumbnail has a marker of its own, so Pillow's full decode decides."""
    from PIL import Image

    try:
        with Image.open(io.BytesIO(data)) as im:
            im.load()
        return True
    except (OSError, SyntaxError, ValueError):
        return False


MAX_IMAGE_BYTES = 256 << 20    # an image or .npy file; a 12-bit 40 MP photo is far less


def _file_bytes(p: Path) -> bytes:
    """The bytes of a regular file of at most MAX_IMAGE_BYTES, its size checked before reading
    (a device such as /dev/zero never ends; a FIFO would block)."""
    try:
        st = os.stat(p)
        if not stat.S_ISREG(st.st_mode):
            raise PerceptionError(f"{p}: not a regular file (a device, FIFO or folder)")
        if st.st_size > MAX_IMAGE_BYTES:
            raise PerceptionError(f"{p}: {st.st_size} bytes; an image file is at most {MAX_IMAGE_BYTES} bytes")
        with open(p, "rb") as f:
            return f.read(MAX_IMAGE_BYTES + 1)
    except OSError as exc:
        raise PerceptionError(f"{p}: cannot read the file ({exc.strerror or exc})") from None


def image_size(data: bytes, p: Path) -> tuple[int, int]:
    """(width, height) from the image's header, before anything is decoded; a format Pillow cannot
    identify, or more than MAX_IMAGE_SIDE a side or MAX_IMAGE_PIXELS in all, is refused (a 30000 x
    30000 PNG of a few KB would take 2.7 GB to decode)."""
    import warnings

    from PIL import Image

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")            # Pillow's decompression-bomb warning: judged here
            with Image.open(io.BytesIO(data)) as im:
                w, h = im.size
    except Image.DecompressionBombError:
        raise PerceptionError(f"{p}: image of more than {MAX_IMAGE_PIXELS} pixels (header)") from None
    except Exception:  # noqa: BLE001 - Pillow raises many kinds for a header it cannot read
        raise PerceptionError(f"{p}: not a readable image (PNG or JPEG expected)") from None
    if max(w, h) > MAX_IMAGE_SIDE or w * h > MAX_IMAGE_PIXELS:
        raise PerceptionError(f"{p}: image is {w}x{h} px; at most {MAX_IMAGE_SIDE} px a side and "
                              f"{MAX_IMAGE_PIXELS} pixels are read")
    return w, h


def _image_bytes(p: Path) -> np.ndarray:
    """The file's bytes, refusing a PNG or JPEG cut short (a copy or a download that stopped):
    OpenCV decodes a truncated JPEG with a grey lower part and only a libjpeg warning. The file's
    size and the image's header are checked before anything is decoded (`image_size`)."""
    data = _file_bytes(p)
    if not data:
        raise PerceptionError(f"{p}: empty file (0 bytes)")
    if data.startswith(b"\x89PNG") and b"IEND" not in data[-64:]:
        raise PerceptionError(f"{p}: truncated PNG (no IEND chunk at the end of its {len(data)} bytes)")
    image_size(data, p)                 # before any decoding, the truncated-JPEG check's included
    if data.startswith(b"\xff\xd8") and not data.rstrip(b"\x00").endswith(b"\xff\xd9") \
            and not _jpeg_complete(data):
        raise PerceptionError(f"{p}: truncated JPEG (no end-of-image marker in its {len(data)} bytes)")
    return np.frombuffer(data, np.uint8)


def _decode(data: np.ndarray, flags: int) -> np.ndarray | None:
    """cv2.imdecode with fd 2 sent to /dev/null meanwhile: libpng and libjpeg print their own
    complaints about a corrupt file there ("libpng error: IDAT: invalid block type"), a second
    line beside the one-line error this module raises."""
    import cv2

    from shelfpick.perception.stdio import redirected_fds

    with redirected_fds(None, os.devnull):
        return cv2.imdecode(data, flags)


def read_rgb(path: str | Path) -> np.ndarray:
    """HxWx3 uint8 RGB; a grey, RGBA or 16-bit image is converted (OpenCV's IMREAD_COLOR)."""
    import cv2

    p = Path(path)
    if not p.exists():          # a device, FIFO or folder: refused by _file_bytes, named as such
        raise PerceptionError(f"{p}: RGB image not found")
    img = _decode(_image_bytes(p), cv2.IMREAD_COLOR)
    if img is None:
        raise PerceptionError(f"{p}: not a readable image (PNG or JPEG expected)")
    return cv2.cvtColor(img, cv2.COLOR_BGR2RGB)


def read_depth(path: str | Path, depth_scale: float) -> np.ndarray:
    """Metric depth (float32 metres, 0 = no data) from a uint16 PNG (65535 = no data too) or a
    .npy file (float: metres, NaN / inf = no data; integer: sensor units)."""
    import cv2

    p = Path(path)
    if not p.exists():          # a device, FIFO or folder: refused by _file_bytes, named as such
        raise PerceptionError(f"{p}: depth image not found")
    if p.suffix.lower() == ".npy":
        raw = _load_npy(p)
        if raw.ndim != 2:
            raise PerceptionError(f"{p}: depth array must be 2-D, got shape {raw.shape}")
        if raw.dtype.kind not in "fiu":
            raise PerceptionError(f"{p}: depth array must be numbers (float metres or integer sensor "
                                  f"units), got dtype {raw.dtype}")
        # float arrays are metres already; integer arrays are sensor units
        depth = raw.astype(np.float32) if raw.dtype.kind == "f" else raw.astype(np.float32) * depth_scale
    else:
        raw = _decode(_image_bytes(p), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise PerceptionError(f"{p}: not a readable depth image (uint16 PNG or .npy expected)")
        if raw.ndim != 2:
            raise PerceptionError(f"{p}: depth image must have one channel, got {raw.shape[2]}")
        if raw.dtype != np.uint16:
            raise PerceptionError(f"{p}: depth image must be uint16 (sensor units of depth_scale m), "
                                  f"got {raw.dtype}")
        # 65535 is the "no return / saturated" code of uint16 depth sensors (the OAK-D capture in
        # shared/realdata uses it); read as metres it would be a surface 65 m away
        depth = np.where(raw == np.iinfo(np.uint16).max, 0, raw).astype(np.float32) * depth_scale
    neg = np.isfinite(depth) & (depth < 0)
    if neg.any():
        raise PerceptionError(f"{p}: {int(neg.sum())} negative depth values (min {float(depth[neg].min()):.3g} m); "
                              "depth is a distance >= 0, 0 = no data")
    depth[~np.isfinite(depth)] = 0.0          # NaN / inf: no measurement
    return depth


def _load_npy(p: Path) -> np.ndarray:
    """A .npy array, its header (shape, dtype) checked against the image bounds before the data
    is read: a header may claim any shape."""
    data = _file_bytes(p)
    f = io.BytesIO(data)
    try:
        version = np.lib.format.read_magic(f)
        shape, _, dtype = (np.lib.format.read_array_header_1_0(f) if version == (1, 0)
                           else np.lib.format.read_array_header_2_0(f))
    except Exception as exc:  # noqa: BLE001 - any header failure is the file's fault
        raise PerceptionError(f"{p}: not a readable .npy depth array ({str(exc)[:200]})") from None
    if dtype.hasobject:
        raise PerceptionError(f"{p}: not a readable .npy depth array (Python objects, which are never unpickled)")
    if len(shape) != 2:
        raise PerceptionError(f"{p}: depth array must be 2-D, got shape {tuple(shape)}")
    if len(shape) == 2 and (max(shape) > MAX_IMAGE_SIDE or shape[0] * shape[1] > MAX_IMAGE_PIXELS):
        raise PerceptionError(f"{p}: depth array is {shape[1]}x{shape[0]}; at most {MAX_IMAGE_SIDE} a side and "
                              f"{MAX_IMAGE_PIXELS} values are read")
    if dtype.itemsize > 16:
        raise PerceptionError(f"{p}: depth array must be numbers (float metres or integer sensor units), "
                              f"got dtype {dtype}")
    try:
        return np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as exc:  # noqa: BLE001 - any numpy load failure is the file's fault
        raise PerceptionError(f"{p}: not a readable .npy depth array ({str(exc)[:200]})") from None


# the median depth of a capture this far from the camera is no shelf a depth sensor sees
DEPTH_RANGE_M = (0.1, 20.0)


def check_depth_units(depth: np.ndarray, depth_scale: float, origin: str, camera_origin: str = "") -> None:
    """Refuse a depth map in the wrong units: metres stored in a uint16 PNG (all 0-2 units),
    millimetres in a float .npy, or a camera file whose depth_scale does not fit the sensor."""
    valid = depth[depth > 0]
    if not valid.size:
        return
    med = float(np.median(valid))
    lo, hi = DEPTH_RANGE_M
    if not lo <= med <= hi:
        cam = f" ({camera_origin})" if camera_origin else ""
        raise PerceptionError(f"{origin}: median depth {med:.3g} m with depth_scale {depth_scale:g}{cam} is outside "
                              f"{lo:g}-{hi:g} m; is the depth in other units (metres in a uint16 PNG, "
                              "millimetres in a float .npy, a wrong depth_scale)?")


# a depth map with fewer than FLAT_SHARE of its valid pixels off its median by FLAT_STEP_M shows no
# shelf: boxes, gaps, the back wall and the floor all make depth steps of centimetres
FLAT_STEP_M = 0.01
FLAT_SHARE = 0.005


def check_depth_structure(depth: np.ndarray, origin: str) -> None:
    """Refuse a flat depth map (one constant value, a wall, a sensor that returns its default):
    segmenting its RGB edges on one plane gives boxes that are not there."""
    valid = depth[depth > 0]
    if valid.size < 2:
        return
    med = float(np.median(valid))
    off = float(np.mean(np.abs(valid - med) > FLAT_STEP_M))
    if off < FLAT_SHARE:
        raise PerceptionError(f"{origin}: depth is flat: {100 * (1 - off):.1f}% of valid pixels within "
                              f"{FLAT_STEP_M * 100:g} cm of {med:.3f} m, no shelf structure; give a real depth "
                              "capture, or perceive without --depth (--front-distance or --box-size)")


def load_capture(rgb: str | Path, depth: str | Path | None, camera: str | Path) -> Capture:
    """Load the files of one capture; errors name the file that is wrong."""
    cam = Camera.load(camera)
    img = read_rgb(rgb)
    dep = read_depth(depth, cam.depth_scale) if depth is not None else None
    validate(img, None, cam, origin=str(rgb), camera_origin=str(camera))  # the RGB's faults name the RGB
    if dep is not None:
        validate(img, dep, cam, origin=str(depth), camera_origin=str(camera))
    if dep is not None:
        check_depth_units(dep, cam.depth_scale, str(depth), str(camera))
    masks, labels = None, {}
    mpath = Path(rgb).with_name("masks.png")
    jpath = Path(rgb).with_name("masks.json")
    if mpath.is_file() and jpath.is_file():
        masks = read_masks(mpath, img.shape[:2])
        labels = read_labels(jpath)
    return Capture(img, dep, cam, masks, labels)


def read_masks(path: Path, shape: tuple[int, int]) -> np.ndarray:
    """The ground-truth label image beside a rendered capture: one channel, the RGB's size."""
    import cv2

    raw = _decode(_image_bytes(path), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.ndim != 2 or raw.shape != tuple(shape):
        got = "not a readable image" if raw is None else f"shape {raw.shape}"
        raise PerceptionError(f"{path}: mask image must be one channel of {shape[1]}x{shape[0]} px, got {got}")
    return raw


def read_labels(path: Path) -> dict[int, str]:
    """`masks.json`: mask label (a decimal integer 1-65535, as a JSON key) -> box id."""
    doc = read_json(path)
    if not isinstance(doc, dict):
        raise FormatError(str(path), "", f"expected an object of mask label -> box id, got {type(doc).__name__}")
    labels: dict[int, str] = {}
    for k, v in doc.items():
        key = k if len(k) <= 40 else k[:40] + "..."
        if not re.fullmatch(r"[0-9]{1,5}", k) or not 0 < int(k) < 65536:
            raise FormatError(str(path), repr(key), f"expected a mask label (an integer 1-65535), got {key!r}")
        if not isinstance(v, str) or not v:
            raise FormatError(str(path), k, f"expected a box id (a non-empty string), got {v!r:.60}")
        labels[int(k)] = check_id(v, str(path), k)
    return labels


def load_capture_dir(d: str | Path) -> Capture:
    """A folder as written by `Capture.save` / `shelfpick render`."""
    d = Path(d)
    depth = d / "depth.png" if (d / "depth.png").is_file() else None
    return load_capture(d / "rgb.png", depth, d / "camera.json")


__all__ = ["Capture", "check_depth_structure", "check_depth_units", "load_capture", "load_capture_dir",
           "read_labels", "read_masks", "read_rgb", "read_depth", "validate"]
