"""Intel RealSense D4xx: live colour + depth aligned to colour, or a recorded .bag file.

`pyrealsense2` is an optional extra (`pip install shelfpick[realsense]`); it is
imported only when a RealSense source is used. Intrinsics come from the
colour stream (depth is aligned to it); the camera pose in the shelf frame is
not something the sensor knows, so it is taken from a camera file or the
default `Camera` pose. No device, an unreadable bag, or no frames within the
timeout are a `PerceptionError`, never a hang.
"""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from shelfpick.perception.capture import Capture
from shelfpick.perception.errors import PerceptionError
from shelfpick.perception.scene import Camera

INSTALL_HINT = "install the optional extra: pip install 'shelfpick[realsense]' (pyrealsense2)"


def _rs():
    try:
        import pyrealsense2 as rs  # type: ignore[import-not-found]
    except ImportError:
        raise PerceptionError(f"RealSense support needs pyrealsense2, which is not installed; "
                              f"{INSTALL_HINT}") from None
    return rs


def camera_from_intrinsics(intr, depth_scale: float, pose: Camera | None = None) -> Camera:
    """A `Camera` from an `rs.intrinsics` (width, height, fx, fy, ppx, ppy) and a pose."""
    base = pose or Camera(int(intr.width), int(intr.height), float(intr.fx), float(intr.fy),
                          float(intr.ppx), float(intr.ppy))
    return replace(base, width=int(intr.width), height=int(intr.height), fx=float(intr.fx),
                   fy=float(intr.fy), cx=float(intr.ppx), cy=float(intr.ppy), depth_scale=float(depth_scale))


class RealSense:
    """A running RealSense pipeline (live device or .bag playback); `grab()` gives one Capture."""

    def __init__(self, bag: str | Path | None = None, *, width: int = 640, height: int = 480, fps: int = 30,
                 serial: str | None = None, pose: Camera | None = None, timeout_ms: int = 5000,
                 warmup: int = 5):
        rs = _rs()
        self._rs = rs
        self.timeout_ms = int(timeout_ms)
        self.pose = pose
        self.source = f"bag:{bag}" if bag else f"realsense:{serial or 'first'}"
        cfg = rs.config()
        if bag is not None:
            p = Path(bag)
            if not p.is_file():
                raise PerceptionError(f"{p}: RealSense recording not found")
            try:
                cfg.enable_device_from_file(str(p), repeat_playback=False)
            except RuntimeError as exc:
                raise PerceptionError(f"{p}: not a readable RealSense .bag ({exc})") from None
        else:
            try:
                devices = rs.context().query_devices()
                n = len(devices)
            except RuntimeError as exc:
                raise PerceptionError(f"RealSense: cannot list devices ({exc})") from None
            if n == 0:
                raise PerceptionError("RealSense: no camera connected (plug in a D4xx, or use a .bag "
                                      "recording or the demo source)")
            if serial:
                cfg.enable_device(serial)
            cfg.enable_stream(rs.stream.depth, width, height, rs.format.z16, fps)
            cfg.enable_stream(rs.stream.color, width, height, rs.format.rgb8, fps)
        self.pipeline = rs.pipeline()
        try:
            profile = self.pipeline.start(cfg)
        except RuntimeError as exc:
            raise PerceptionError(f"{self.source}: cannot start the RealSense pipeline ({exc})") from None
        if bag is not None:
            try:
                profile.get_device().as_playback().set_real_time(False)
            except RuntimeError:
                pass
        self.depth_scale = float(profile.get_device().first_depth_sensor().get_depth_scale())
        self.align = rs.align(rs.stream.color)
        for _ in range(0 if bag is not None else warmup):  # auto-exposure settles
            self._frames()

    def _frames(self):
        try:
            return self.pipeline.wait_for_frames(self.timeout_ms)
        except RuntimeError as exc:
            raise PerceptionError(f"{self.source}: no frames within {self.timeout_ms} ms ({exc})") from None

    def grab(self) -> Capture:
        rs = self._rs
        frames = self.align.process(self._frames())
        color, depth = frames.get_color_frame(), frames.get_depth_frame()
        if not color or not depth:
            raise PerceptionError(f"{self.source}: frame set without colour or depth")
        intr = color.profile.as_video_stream_profile().intrinsics
        rgb = np.asanyarray(color.get_data()).copy()
        if color.profile.format() == rs.format.bgr8:
            rgb = rgb[..., ::-1].copy()
        z = np.asanyarray(depth.get_data()).astype(np.float32) * self.depth_scale
        cam = camera_from_intrinsics(intr, self.depth_scale, self.pose)
        return Capture(rgb.astype(np.uint8), z, cam)

    def close(self) -> None:
        try:
            self.pipeline.stop()
        except RuntimeError:
            pass

    def __enter__(self) -> "RealSense":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def capture_live(pose: Camera | None = None, timeout_ms: int = 5000, **kw) -> Capture:
    """One aligned frame from the first connected D4xx."""
    with RealSense(None, pose=pose, timeout_ms=timeout_ms, **kw) as cam:
        return cam.grab()


def capture_bag(path: str | Path, pose: Camera | None = None, timeout_ms: int = 5000) -> Capture:
    """The first aligned frame of a recorded .bag file."""
    with RealSense(path, pose=pose, timeout_ms=timeout_ms) as cam:
        return cam.grab()
