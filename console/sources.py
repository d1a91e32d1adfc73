"""Where the console's captures come from: a demo shelf, a folder of files, a RealSense camera or recording.

`open_source(spec)` understands:

- `demo` (or `demo:NAME`): the shipped demo shelves `static/demo/*.json`
  (or one of them), rendered with `perception.render.render`, a new look
  (seed) per capture. After the robot worked on a shelf, the next capture
  shows that shelf as the robot left it (the world of its last look); once
  it is empty, the next demo shelf in turn. The true scene is known,
  so the simulated robot can execute against it. With no demo files a small
  built-in shelf is used.
- `files:DIR`: `rgb.png`, `depth.png`, `camera.json` as written by
  `shelfpick render` or a camera tool; re-read on every capture (a tool may
  overwrite them). `truth.json` beside them (a scene) is the truth if present.
- `realsense[?camera=FILE]`: a live Intel RealSense D4xx (pyrealsense2, an
  optional extra); FILE gives the camera pose in the shelf frame.
- `bag:FILE[?camera=FILE]`: a RealSense recording, one frame per capture.

A camera that fails raises `SourceError` (a ShelfpickError) naming the source
and the cause; the console shows it and keeps running.

`look_again(world, step, attempt=0)` is the console's look after a robot step (closed
loop, docs/console.md "Verification"): the demo renders the simulated robot's
true shelf as it now stands (`world`; unknown for another robot: SourceError,
so the robot is held); files re-reads the folder and returns None when the
images did not change since the last read (no new frame: the robot is held);
RealSense grabs a new frame.
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol
from urllib.parse import parse_qs

from shelfpick.perception.capture import Capture
from shelfpick.perception.errors import ShelfpickError
from shelfpick.perception.scene import Box, Camera, Scene, Shelf

DEMO_DIR = Path(__file__).resolve().parent.parent / "static" / "demo"


class SourceError(ShelfpickError):
    """A capture source that cannot be opened or that failed to deliver a frame."""


@dataclass(frozen=True, eq=False)
class Frame:
    capture: Capture
    truth: Scene | None
    name: str


class Source(Protocol):
    name: str

    def capture(self) -> Frame: ...


def builtin_scene() -> Scene:
    """A small shelf for when no demo files are installed: a stack of two, and a long box bridging two.

    Picking `b0` safely needs `b1` (on top of it) out first; pulling `b2` or
    `b4` first drops the bridging `b3`.
    """
    return Scene(Shelf(1.0, 0.30, 1.60), (
        Box("b0", (0.31, 0.25, 0.23), (-0.28, 0.135, 0.115)),
        Box("b1", (0.20, 0.20, 0.20), (-0.28, 0.110, 0.330)),
        Box("b2", (0.20, 0.20, 0.20), (0.00, 0.110, 0.100)),
        Box("b3", (0.50, 0.17, 0.17), (0.175, 0.095, 0.285)),
        Box("b4", (0.20, 0.20, 0.20), (0.35, 0.110, 0.100)),
    ), source="shelfpick built-in demo shelf")


def _guard(name: str, fn) -> Any:
    """Run a capture step; anything that is not already a user-facing error becomes a SourceError."""
    try:
        return fn()
    except ShelfpickError:
        raise
    except Exception as exc:  # noqa: BLE001 - a camera or renderer fault is shown, not a crash
        raise SourceError(f"{name}: capture failed ({exc.__class__.__name__}: {exc})") from None


class DemoSource:
    """Synthetic captures of known shelves: the demo and the tests run without a camera."""

    def __init__(self, scenes: list[tuple[str, Scene]], seed: int = 0, camera: Camera | None = None,
                 name: str = "demo") -> None:
        if not scenes:
            raise SourceError("demo: no demo shelves")
        self.scenes = scenes
        self.seed = int(seed)
        self.camera = camera
        self.name = name
        self._n = 0
        self._last: tuple[str, int] = (scenes[0][0], 0)   # the shelf and look number of the last capture
        # the shelf as the robot left it (the world of its last look): the next capture shows it
        self._worked: Scene | None = None
        self._shelf = -1                  # index of the demo shelf shown (advanced when one is needed)
        self._lock = threading.Lock()

    @classmethod
    def from_dir(cls, folder: Path = DEMO_DIR, pick: str | None = None, seed: int = 0) -> "DemoSource":
        files = sorted(folder.glob("*.json")) if folder.is_dir() else []
        if pick:
            files = [f for f in files if f.stem == pick]
            if not files:
                have = ", ".join(sorted(f.stem for f in folder.glob("*.json"))) if folder.is_dir() else "none"
                raise SourceError(f"demo:{pick}: no demo shelf {pick!r} in {folder} (have: {have})")
        scenes = [(f.stem, Scene.load(f)) for f in files]
        if not scenes:
            scenes = [("builtin", builtin_scene())]
        return cls(scenes, seed, name=f"demo:{pick}" if pick else "demo")

    def capture(self) -> Frame:
        """The shelf the robot last worked on, as it now stands; a fresh demo shelf at the start and
        once the robot has emptied it (the next of the demo shelves, in turn)."""
        from shelfpick.perception.render import render

        with self._lock:
            n = self._n
            self._n += 1
            worked, self._worked = self._worked, None
            if worked is not None and worked.boxes:
                label = self._last[0]
                scene, note = worked, " (as the robot left it)"
            else:
                self._shelf += 1
                label, scene = self.scenes[self._shelf % len(self.scenes)]
                note = " (the robot emptied the last shelf: the next demo shelf)" if worked is not None else ""
        cap = _guard(f"demo:{label}", lambda: render(scene, self.camera, seed=self.seed + n))
        with self._lock:
            self._last = (label, n)
            if worked is not None and worked.boxes:
                self._worked = worked       # until the robot changes it again: the same shelf
        return Frame(cap, scene, f"demo:{label}#{n}{note}")

    def look_again(self, world: Scene | None, step: int, attempt: int = 0) -> Frame:
        """The simulated robot's true shelf as it now stands, rendered (a new look: seeded by step
        and attempt; the console looks a second time to confirm a difference)."""
        from shelfpick.perception.render import render

        with self._lock:
            label, n = self._last
            if world is not None:
                self._worked = world
        if world is None:
            raise SourceError(f"demo:{label}: the shelf after the robot's step is not known (the demo "
                              f"renders the simulated robot's shelf; this robot is not simulated here)")
        seed = self.seed + n + 1000 * (step + 1) + 1_000_003 * attempt
        cap = _guard(f"demo:{label}", lambda: render(world, self.camera, seed=seed))
        return Frame(cap, world, f"demo:{label}#{n}/after step {step + 1}" + (f" (look {attempt + 1})" if attempt else ""))


class FilesSource:
    """A folder with rgb.png, depth.png, camera.json (and maybe truth.json), read at each capture."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self.name = f"files:{self.folder}"
        self._seen: str | None = None   # fingerprint of the images last read
        if not self.folder.is_dir():
            raise SourceError(f"{self.folder}: capture folder not found (files:DIR needs rgb.png, depth.png, "
                              f"camera.json)")

    def capture(self) -> Frame:
        from shelfpick.perception.capture import load_capture_dir

        for need in ("rgb.png", "camera.json"):
            if not (self.folder / need).is_file():
                raise SourceError(f"{self.folder / need}: missing (files:DIR needs rgb.png, depth.png, camera.json)")
        fingerprint = self._fingerprint()
        cap = _guard(self.name, lambda: load_capture_dir(self.folder))
        truth_path = self.folder / "truth.json"
        truth = Scene.load(truth_path) if truth_path.is_file() else None
        self._seen = fingerprint
        return Frame(cap, truth, f"files:{self.folder.name}")

    def _fingerprint(self) -> str:
        """What the folder's images are now (a camera tool overwrites them with each new frame)."""
        import hashlib

        h = hashlib.sha256()
        for name in ("rgb.png", "depth.png", "camera.json"):
            p = self.folder / name
            h.update(name.encode())
            h.update(p.read_bytes() if p.is_file() else b"-")
        return h.hexdigest()

    def look_again(self, world: Scene | None, step: int, attempt: int = 0) -> Frame | None:
        """The folder's next frame; None when its images are those already read (no new frame)."""
        if _guard(self.name, self._fingerprint) == self._seen:
            return None
        return self.capture()


class RealSenseSource:
    """A live RealSense or a .bag recording; the pipeline is opened at the first capture and kept."""

    def __init__(self, bag: str | None = None, camera_file: str | None = None) -> None:
        self.bag = bag
        self.name = f"bag:{bag}" if bag else "realsense"
        if bag is not None and not Path(bag).is_file():
            raise SourceError(f"{bag}: RealSense recording not found")
        self.pose = Camera.load(camera_file) if camera_file else None
        self._cam: Any = None
        self._n = 0
        self._lock = threading.Lock()

    def _open(self) -> Any:
        from shelfpick.perception.realsense import RealSense

        return RealSense(self.bag, pose=self.pose)

    def capture(self) -> Frame:
        with self._lock:
            if self._cam is None:
                self._cam = _guard(self.name, self._open)
            try:
                cap = _guard(self.name, self._cam.grab)
            except ShelfpickError:
                self.close_locked()
                if self.bag is None:
                    raise
                self._cam = _guard(self.name, self._open)  # end of the recording: start over
                cap = _guard(self.name, self._cam.grab)
            self._n += 1
            return Frame(cap, None, f"{self.name}#{self._n}")

    def look_again(self, world: Scene | None, step: int, attempt: int = 0) -> Frame:
        """A new frame of the live camera (or the recording's next one)."""
        return self.capture()

    def close_locked(self) -> None:
        if self._cam is not None:
            try:
                self._cam.close()
            finally:
                self._cam = None

    def close(self) -> None:
        with self._lock:
            self.close_locked()


def open_source(spec: str, seed: int = 0) -> Source:
    """`demo` | `demo:NAME` | `files:DIR` | `realsense[?camera=FILE]` | `bag:FILE[?camera=FILE]`."""
    s = spec.strip()
    base, _, query = s.partition("?")
    q = parse_qs(query)
    bad = set(q) - {"camera"}
    if bad:
        raise SourceError(f"source {spec!r}: unknown option {sorted(bad)[0]!r} (known: camera)")
    camera_file = q["camera"][-1] if "camera" in q else None
    if base == "demo" or base.startswith("demo:"):
        pick = base[5:] or None
        src = DemoSource.from_dir(DEMO_DIR, pick, seed)
        if camera_file:
            src.camera = Camera.load(camera_file)
        return src
    if base.startswith("files:"):
        if not base[6:]:
            raise SourceError(f"source {spec!r}: files:DIR needs a folder")
        return FilesSource(base[6:])
    if base == "realsense":
        return RealSenseSource(None, camera_file)
    if base.startswith("bag:"):
        if not base[4:]:
            raise SourceError(f"source {spec!r}: bag:FILE needs a .bag file")
        return RealSenseSource(base[4:], camera_file)
    raise SourceError(f"source {spec!r}: expected demo, demo:NAME, files:DIR, realsense or bag:FILE")


__all__ = ["Frame", "Source", "SourceError", "DemoSource", "FilesSource", "RealSenseSource", "open_source",
           "builtin_scene", "DEMO_DIR"]
