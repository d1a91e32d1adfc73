"""A RealSense recording made without a camera: captures played into a pyrealsense2 software
device and recorded, so the `bag:FILE` path (perception.realsense, console `--source bag:FILE`)
can be tested end to end on rendered frames with known boxes.

librealsense 2.59 (the pip wheel) records rosbag2 (`.db3`; its recorder refuses a `.bag` name)
and plays both. Depth and colour share the capture's intrinsics, identity extrinsics, depth in
millimetres; the playback's align-to-colour then leaves ~5% of depth pixels empty (edges).
"""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from shelfpick.perception.capture import Capture
from shelfpick.perception.errors import PerceptionError


def _profiles(rs, sensor, cam):
    intr = rs.intrinsics()
    intr.width, intr.height = cam.width, cam.height
    intr.fx, intr.fy, intr.ppx, intr.ppy = cam.fx, cam.fy, cam.cx, cam.cy
    intr.model, intr.coeffs = rs.distortion.none, [0.0] * 5
    out = []
    for uid, (kind, fmt, bpp) in enumerate(((rs.stream.depth, rs.format.z16, 2),
                                            (rs.stream.color, rs.format.rgb8, 3)), start=1):
        vs = rs.video_stream()
        vs.type, vs.fmt, vs.bpp, vs.index, vs.uid = kind, fmt, bpp, 0, uid
        vs.width, vs.height, vs.fps, vs.intrinsics = cam.width, cam.height, 30, intr
        out.append(rs.video_stream_profile(sensor.add_video_stream(vs)))
    ext = rs.extrinsics()
    ext.rotation, ext.translation = [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0], [0.0, 0.0, 0.0]
    out[0].register_extrinsics_to(out[1], ext)
    return out


def record(path: str | Path, captures: Sequence[Capture]) -> Path:
    """Write `captures` (same camera, with depth) as a RealSense recording at `path` (.db3)."""
    try:
        import pyrealsense2 as rs
    except ImportError:
        raise PerceptionError("pyrealsense2 is not installed (pip install 'shelfpick[realsense]')") from None
    if not captures or any(c.depth is None for c in captures):
        raise PerceptionError("a recording needs at least one capture, each with depth")
    cam = captures[0].camera
    dev = rs.software_device()
    sensor = dev.add_sensor("Depth")
    dprof, cprof = _profiles(rs, sensor, cam)
    sensor.add_read_only_option(rs.option.depth_units, float(cam.depth_scale))
    try:
        rec = rs.recorder(str(path), dev)
    except RuntimeError as exc:
        raise PerceptionError(f"{path}: librealsense cannot record there ({exc})") from None
    sensor.open([dprof, cprof])
    sensor.start(rs.frame_queue(10))
    for i, cap in enumerate(captures):
        depth = np.clip(np.round(np.nan_to_num(cap.depth) / cam.depth_scale), 0, 65535).astype(np.uint16)
        for prof, data, bpp in ((dprof, depth, 2), (cprof, np.ascontiguousarray(cap.rgb), 3)):
            f = rs.software_video_frame()
            f.pixels, f.bpp, f.stride = data, bpp, cam.width * bpp
            f.timestamp, f.frame_number, f.profile = i * 1000.0 / 30, i, prof
            f.domain = rs.timestamp_domain.hardware_clock
            sensor.on_video_frame(f)
    sensor.stop()
    sensor.close()
    del rec                                   # the recorder writes the file when it goes
    return Path(path)


__all__ = ["record"]
