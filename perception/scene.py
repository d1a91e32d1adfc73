"""Scene and camera documents (`shelfpick.scene/1`, `shelfpick.camera/1`).

These frozen dataclasses are the contract between perception, planning and
the console (see ../shared/FORMATS.md). Perception produces scenes, so they
live here; planning and the console import them, never the reverse.
Readers validate everything and raise `FormatError` naming origin, field and
value; extra keys are kept in `extra` so a round trip loses nothing.
"""
from __future__ import annotations

import json
import math
import os
import stat
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

from shelfpick.perception.errors import FormatError

SCENE_FORMAT = "shelfpick.scene/1"
CAMERA_FORMAT = "shelfpick.camera/1"

Vec3 = tuple[float, float, float]
Quat = tuple[float, float, float, float]  # scalar first: w, x, y, z

IDENTITY: Quat = (1.0, 0.0, 0.0, 0.0)


# --------------------------------------------------------------------------
# small validated readers
def _num(value: Any, origin: str, fld: str, *, positive: bool = False,
         nonneg: bool = False, within: tuple[float, float] | None = None, unit: str = "m") -> float:
    """A finite number; `within` (lo, hi) is the plausible range of a physical quantity."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise FormatError(origin, fld, f"expected a number, got {value!r}")
    v = float(value)
    if not math.isfinite(v):
        raise FormatError(origin, fld, f"must be finite, got {value!r}")
    if positive and v <= 0:
        raise FormatError(origin, fld, f"must be > 0, got {value!r}")
    if nonneg and v < 0:
        raise FormatError(origin, fld, f"must be >= 0, got {value!r}")
    if within is not None and not within[0] <= v <= within[1]:
        raise FormatError(origin, fld, f"must be within [{within[0]:g}, {within[1]:g}] {unit}, got {value!r}")
    return v


def _vec(value: Any, n: int, origin: str, fld: str, *, positive: bool = False,
         within: tuple[float, float] | None = None) -> tuple:
    if not isinstance(value, (list, tuple)) or len(value) != n:
        raise FormatError(origin, fld, f"expected a list of {n} numbers, got {value!r}")
    return tuple(_num(v, origin, f"{fld}[{i}]", positive=positive, within=within) for i, v in enumerate(value))


# --------------------------------------------------------------------------
# plausible physical quantities (docs/formats.md "Bounds"): a value outside is a broken file or a
# unit mistake, never a shelf; refused naming the field before any physics or memory is spent on it
SHELF_M = (0.05, 20.0)        # shelf interior width, depth, height (the cell file's bound too)
BOX_SIZE_M = (0.01, 5.0)      # each extent of a box
BOX_MASS_KG = (1e-3, 1000.0)
CAMERA_POSITION_M = 50.0      # |each coordinate| of the camera, shelf frame
CAMERA_FOCAL_PX = (1.0, 1e6)
CAMERA_DEPTH_SCALE = (1e-6, 1.0)   # metres per depth unit
MAX_IMAGE_SIDE = 12_000       # px, a camera's width or height (and an image's)
MAX_IMAGE_PIXELS = 40_000_000  # px, width x height (a 3647x5087 phone photo is 18.6 million)
MAX_ID_CHARS = 64             # a box id


def check_id(value: Any, origin: str, fld: str) -> str:
    """A box id: 1-64 printable characters (str.isprintable: no control characters, line breaks,
    escape sequences, NUL, format characters or lone surrogates), no space at either end; ids are
    echoed to terminals, logs and web pages, so anything else is refused, shown escaped."""
    if not isinstance(value, str) or not value:
        raise FormatError(origin, fld, f"expected a non-empty string, got {value!r}")
    if len(value) > MAX_ID_CHARS or not value.isprintable() or value != value.strip():
        shown = ascii(value) if len(value) <= MAX_ID_CHARS else ascii(value[:MAX_ID_CHARS]) + "..."
        raise FormatError(origin, fld, f"a box id is 1-{MAX_ID_CHARS} printable characters (no control character, "
                          f"line break, escape, NUL or surrogate; no space at either end), got {shown}")
    return value


_UNIT_AS_WRITTEN = 1e-9   # |q| this near 1 is a unit quaternion as written (rounding), not a slip


def _quat(value: Any, origin: str, fld: str) -> Quat:
    q = _vec(value, 4, origin, fld)
    norm = math.sqrt(sum(c * c for c in q))
    if abs(norm - 1.0) > 1e-3:
        if norm < 1e-6:
            raise FormatError(origin, fld, f"quaternion has zero length: {list(value)!r}")
        raise FormatError(origin, fld, f"quaternion is not unit length (|q|={norm:.4f}): {list(value)!r}")
    if abs(norm - 1.0) <= _UNIT_AS_WRITTEN:
        # kept bit for bit: dividing a unit quaternion by its norm again moves its last digits (a
        # third of random ones), and a stack of boxes turns that into another plan, so a scene
        # read back would not plan as the one written
        return q  # type: ignore[return-value]
    return tuple(c / norm for c in q)  # type: ignore[return-value]


def _req(doc: Mapping, key: str, origin: str, prefix: str = "") -> Any:
    if key not in doc:
        raise FormatError(origin, f"{prefix}{key}", "missing required key")
    return doc[key]


def _obj(value: Any, origin: str, fld: str) -> Mapping:
    if not isinstance(value, Mapping):
        raise FormatError(origin, fld, f"expected an object, got {type(value).__name__}")
    return value


MAX_JSON_BYTES = 64 << 20   # a scene of 500 boxes is ~150 KB; a plan or camera far less
MAX_JSON_DEPTH = 32         # our documents nest 4 levels; extra keys may add a few
MAX_INT_DIGITS = 20         # an integer field (width, mask label) never needs more
MAX_BOXES = 500             # boxes in one scene: a shelf holds tens; planning is exponential beyond


class _Odd:
    """A JSON token kept for the validating walk to name with its field: NaN/Infinity, a huge integer."""

    def __init__(self, text: str) -> None:
        self.text = text

    def __repr__(self) -> str:
        return self.text if len(self.text) <= 24 else f"{self.text[:12]}...({len(self.text)} digits)"


def _parse_int(text: str) -> int | _Odd:
    return int(text) if len(text.lstrip("-")) <= MAX_INT_DIGITS else _Odd(text)


def _parse_float(text: str) -> float | _Odd:
    v = float(text)
    return v if math.isfinite(v) else _Odd(text)


def _open_regular(p: Path) -> bytes:
    """The bytes of a regular file; a FIFO, device or folder is refused before it is read (a FIFO
    would block, a device never end)."""
    try:
        fd = os.open(p, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise FormatError(str(p), "", "file not found") from None
    except OSError as exc:
        raise FormatError(str(p), "", f"cannot read file ({exc.__class__.__name__}: {exc.strerror})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            kind = ("a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                    else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "a socket")
            raise FormatError(str(p), "", f"{kind}, not a regular file")
        if st.st_size > MAX_JSON_BYTES:
            raise FormatError(str(p), "", f"{st.st_size} bytes; a document is at most {MAX_JSON_BYTES} bytes")
        with os.fdopen(fd, "rb", closefd=True) as f:
            fd = -1
            return f.read(MAX_JSON_BYTES + 1)
    except OSError as exc:
        raise FormatError(str(p), "", f"cannot read file ({exc.__class__.__name__}: {exc.strerror})") from None
    finally:
        if fd >= 0:
            os.close(fd)


def _index(item: Any, i: int) -> str:
    """How a field path names a list item: `id=b3` for a box (as the validators do), else its index."""
    bid = item.get("id") if isinstance(item, dict) else None
    return f"id={bid}" if isinstance(bid, str) and bid and len(bid) <= 40 else str(i)


def _check_tree(doc: Any, origin: str) -> None:
    """Walk the parsed document without recursion: too deep, NaN/Infinity or a huge integer
    anywhere (extra keys included) is refused naming its field."""
    todo: list[tuple[Any, str, int]] = [(doc, "", 0)]
    while todo:
        node, path, depth = todo.pop()
        if isinstance(node, _Odd):
            what = "a finite number" if not node.text.lstrip("-").isdigit() else \
                f"an integer of at most {MAX_INT_DIGITS} digits"
            raise FormatError(origin, path or "document", f"expected {what}, got {node!r}")
        if depth > MAX_JSON_DEPTH:
            where = path if len(path) <= 80 else f"{path[:40]}...{path[-30:]}"
            raise FormatError(origin, where, f"nested deeper than {MAX_JSON_DEPTH} levels")
        if isinstance(node, dict):
            todo.extend((v, f"{path}.{k}" if path else str(k), depth + 1) for k, v in node.items())
        elif isinstance(node, list):
            todo.extend((v, f"{path}[{_index(v, i)}]", depth + 1) for i, v in enumerate(node))


def read_json(path: str | Path) -> Any:
    """Read a JSON file; a missing, unreadable, special (FIFO, device) or malformed file, nesting
    deeper than MAX_JSON_DEPTH, NaN/Infinity or a huge number raise FormatError naming the field."""
    p = Path(path)
    data = _open_regular(p)
    if len(data) > MAX_JSON_BYTES:
        raise FormatError(str(p), "", f"more than {MAX_JSON_BYTES} bytes; a document is smaller")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(str(p), "", f"cannot read file (not UTF-8 text: byte {exc.start})") from None
    try:
        doc = json.loads(text, parse_int=_parse_int, parse_float=_parse_float, parse_constant=_Odd)
    except json.JSONDecodeError as exc:
        raise FormatError(str(p), "", f"malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise FormatError(str(p), "document", f"nested deeper than {MAX_JSON_DEPTH} levels") from None
    _check_tree(doc, str(p))
    return doc


def output_path(path: str | Path, flag: str = "") -> Path:
    """Where an output file may be written atomically: a new path or an existing regular file (a
    symlink to one: the file it points at). A device, FIFO, socket or folder, or a symlink to one,
    is refused with a FormatError naming it: renaming a temp file over `/dev/null` would replace
    the device node for the whole system (a FIFO or a folder is no file to replace either)."""
    p = Path(path)
    try:
        st = os.stat(p)                 # follows symlinks: a link is judged by what it points at
    except OSError:                     # nothing there (or no folder): the write itself says why it fails
        if p.is_symlink():              # a dangling link: writing would replace the link itself
            raise FormatError(str(p), flag, "a symlink to nothing; give a file path") from None
        return p
    if not stat.S_ISREG(st.st_mode):
        kind = ("a folder" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "a socket")
        raise FormatError(str(p), flag, f"{kind}, not a regular file; an output is written only to a new path "
                          "or over a regular file")
    return Path(os.path.realpath(p))


def write_text(path: str | Path, text: str, flag: str = "") -> Path:
    """Write atomically (temp file + rename) so a crash never leaves half a file; only over a
    regular file or a new path (`output_path`). Returns the file written."""
    p = output_path(path, flag)
    p.parent.mkdir(parents=True, exist_ok=True)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(text, encoding="utf-8")
    tmp.replace(p)
    return p


def write_json(path: str | Path, doc: Any, flag: str = "") -> None:
    """`doc` as indented JSON, atomically, only over a regular file or a new path (`write_text`)."""
    write_text(path, json.dumps(doc, indent=2) + "\n", flag)


# --------------------------------------------------------------------------
# quaternion helpers (scalar first), kept here so every package agrees
def quat_to_matrix(q: Sequence[float]) -> list[list[float]]:
    w, x, y, z = q
    return [
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ]


def wxyz_to_xyzw(q: Sequence[float]) -> tuple[float, float, float, float]:
    return (q[1], q[2], q[3], q[0])


def xyzw_to_wxyz(q: Sequence[float]) -> Quat:
    return (q[3], q[0], q[1], q[2])


def yaw_quat(yaw: float) -> Quat:
    """Rotation about +z (an in-plane turn of a box standing on the floor)."""
    return (math.cos(yaw / 2), 0.0, 0.0, math.sin(yaw / 2))


# --------------------------------------------------------------------------
# The method's box types, (size along x, y, z) in metres as they stand on the shelf: the one table
# the generators, the renderer's training scenes and perception's box catalogue all read.
BOX_TYPES: dict[str, tuple[float, float, float]] = {
    "carton": (0.23, 0.31, 0.25),
    "cube": (0.20, 0.20, 0.20),
    "long": (0.50, 0.17, 0.17),
}


@dataclass(frozen=True)
class Shelf:
    """Interior of the shelf, metres: x in [-w/2, w/2], y in [0, depth], z in [0, height]."""

    width: float = 1.0
    depth: float = 0.30
    height: float = 1.60

    def to_json(self) -> dict:
        return {"width": self.width, "depth": self.depth, "height": self.height}

    @classmethod
    def from_json(cls, doc: Any, origin: str = "") -> "Shelf":
        doc = _obj(doc, origin, "shelf")
        return cls(*(_num(_req(doc, k, origin, "shelf."), origin, f"shelf.{k}", positive=True, within=SHELF_M)
                     for k in ("width", "depth", "height")))


@dataclass(frozen=True)
class Box:
    """One rigid box: full extents `size` along its own x/y/z, centre `position`."""

    id: str
    size: Vec3
    position: Vec3
    orientation: Quat = IDENTITY
    mass: float | None = None
    depth_known: bool = True
    mask_label: int | None = None
    extra: Mapping[str, Any] = field(default_factory=dict, compare=False, hash=False)

    @property
    def contradicted(self) -> bool:
        """Whether perception named this box in a warning that its faces cannot all be right
        (`perceived.contradicted`, docs/formats.md): planning does not call a plan touching it safe."""
        return (self.extra.get("perceived") or {}).get("contradicted") is True

    @property
    def front_y(self) -> float:
        """y of the front face centre, for an upright box turned about z only."""
        return self.front_center[1]

    @property
    def front_center(self) -> Vec3:
        """Centre of the face on the box's local -y side, in the shelf frame."""
        r = quat_to_matrix(self.orientation)
        h = self.size[1] / 2
        return tuple(self.position[i] - r[i][1] * h for i in range(3))  # type: ignore[return-value]

    @property
    def top_z(self) -> float:
        """Highest z of the box's corners."""
        return max(c[2] for c in self.corners())

    def corners(self) -> list[Vec3]:
        r = quat_to_matrix(self.orientation)
        out = []
        for sx in (-0.5, 0.5):
            for sy in (-0.5, 0.5):
                for sz in (-0.5, 0.5):
                    local = (sx * self.size[0], sy * self.size[1], sz * self.size[2])
                    out.append(tuple(self.position[i] + sum(r[i][j] * local[j] for j in range(3))
                                     for i in range(3)))
        return out  # type: ignore[return-value]

    def with_depth(self, depth: float) -> "Box":
        """Same box with a new extent along its own y, front face kept in place."""
        r = quat_to_matrix(self.orientation)
        front = self.front_center
        pos = tuple(front[i] + r[i][1] * depth / 2 for i in range(3))
        return replace(self, size=(self.size[0], depth, self.size[2]), position=pos)  # type: ignore[arg-type]

    def to_json(self) -> dict:
        doc: dict[str, Any] = dict(self.extra)
        doc.update({"id": self.id, "size": list(self.size), "position": list(self.position),
                    "orientation": list(self.orientation)})
        if self.mass is not None:
            doc["mass"] = self.mass
        if not self.depth_known:
            doc["depth_known"] = False
        if self.mask_label is not None:
            doc["mask_label"] = self.mask_label
        return doc

    @classmethod
    def from_json(cls, doc: Any, origin: str = "", where: str = "box") -> "Box":
        doc = _obj(doc, origin, where)
        bid = check_id(_req(doc, "id", origin, f"{where}."), origin, f"{where}.id")
        w = f"boxes[id={bid}]"
        size = _vec(_req(doc, "size", origin, f"{w}."), 3, origin, f"{w}.size", positive=True, within=BOX_SIZE_M)
        pos = _vec(_req(doc, "position", origin, f"{w}."), 3, origin, f"{w}.position")
        quat = _quat(doc.get("orientation", list(IDENTITY)), origin, f"{w}.orientation")
        mass = doc.get("mass")
        if mass is not None:
            mass = _num(mass, origin, f"{w}.mass", positive=True, within=BOX_MASS_KG, unit="kg")
        dk = doc.get("depth_known", True)
        if not isinstance(dk, bool):
            raise FormatError(origin, f"{w}.depth_known", f"expected true or false, got {dk!r}")
        label = doc.get("mask_label")
        if label is not None and (isinstance(label, bool) or not isinstance(label, int) or label < 1):
            raise FormatError(origin, f"{w}.mask_label", f"expected a positive integer, got {label!r}")
        known = {"id", "size", "position", "orientation", "mass", "depth_known", "mask_label"}
        extra = {k: v for k, v in doc.items() if k not in known}
        return cls(bid, size, pos, quat, mass, dk, label, extra)  # type: ignore[arg-type]


@dataclass(frozen=True)
class Camera:
    """Pinhole camera (OpenCV frame) and its pose in the shelf frame (camera to shelf)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    depth_scale: float = 0.001
    position: Vec3 = (0.0, -1.04, 0.80)
    orientation: Quat = (0.7071067811865476, -0.7071067811865476, 0.0, 0.0)

    def to_json(self) -> dict:
        return {"format": CAMERA_FORMAT, "width": self.width, "height": self.height,
                "fx": self.fx, "fy": self.fy, "cx": self.cx, "cy": self.cy,
                "depth_scale": self.depth_scale,
                "pose": {"position": list(self.position), "orientation": list(self.orientation)}}

    @classmethod
    def from_json(cls, doc: Any, origin: str = "", where: str = "") -> "Camera":
        doc = _obj(doc, origin, where or "camera")
        p = f"{where}." if where else ""
        fmt = doc.get("format", CAMERA_FORMAT)
        if fmt != CAMERA_FORMAT:
            raise FormatError(origin, f"{p}format", f"expected {CAMERA_FORMAT!r}, got {fmt!r}")
        vals = {}
        for k in ("width", "height"):
            v = _req(doc, k, origin, p)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or v != int(v) or v <= 0:
                raise FormatError(origin, f"{p}{k}", f"expected a positive integer, got {v!r}")
            if v > MAX_IMAGE_SIDE:
                raise FormatError(origin, f"{p}{k}", f"must be at most {MAX_IMAGE_SIDE} px, got {v!r}")
            vals[k] = int(v)
        for k in ("fx", "fy"):
            vals[k] = _num(_req(doc, k, origin, p), origin, f"{p}{k}", positive=True, within=CAMERA_FOCAL_PX,
                           unit="px")
        for k, side in (("cx", vals["width"]), ("cy", vals["height"])):
            vals[k] = _num(_req(doc, k, origin, p), origin, f"{p}{k}", within=(-10.0 * side, 11.0 * side), unit="px")
        scale = _num(doc.get("depth_scale", 0.001), origin, f"{p}depth_scale", positive=True,
                     within=CAMERA_DEPTH_SCALE, unit="m per unit")
        pose = _obj(_req(doc, "pose", origin, p), origin, f"{p}pose")
        pos = _vec(_req(pose, "position", origin, f"{p}pose."), 3, origin, f"{p}pose.position",
                   within=(-CAMERA_POSITION_M, CAMERA_POSITION_M))
        quat = _quat(_req(pose, "orientation", origin, f"{p}pose."), origin, f"{p}pose.orientation")
        return cls(vals["width"], vals["height"], vals["fx"], vals["fy"], vals["cx"], vals["cy"],
                   scale, pos, quat)

    @classmethod
    def load(cls, path: str | Path) -> "Camera":
        return cls.from_json(read_json(path), str(path))

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json())


MAX_UNEXPLAINED = 200        # unexplained regions in one scene (perception reports far fewer)
MAX_COLUMNS = 400            # columns of one region's seen surface


def _box_bounds(lo: Vec3, hi: Vec3, origin: str, fld: str) -> None:
    if any(a > b for a, b in zip(lo, hi)):
        raise FormatError(origin, fld, f"min {list(lo)!r} exceeds max {list(hi)!r}")


# what counts as unexplained matter (perception/unexplained.py finds it, planning/unexplained.py
# keeps clear of it); here, beside the record, so that planning needs no OpenCV to read them:
# a point this close (m) to a box's face prism or a shelf board is explained by it: faces are
# measured to ~1 cm and `make_valid` moves boxes by up to a few mm more
EXPLAIN_TOL = 0.02
# the shelf volume reaches this far (m) in front of its front plane: boxes overhang it
FRONT_REACH = 0.10


@dataclass(frozen=True)
class Unexplained:
    """Matter the depth image shows inside the shelf that no perceived box (nor the shelf) explains.

    `min`/`max`: the seen surface's bounds in the shelf frame (y: nearest and farthest seen
    point); what lies behind it is unknown, so planning takes it as reaching back to the back
    wall. `columns`: the seen surface as x-z rectangles (x0, x1, z0, z1, nearest y), so an
    L-shaped region does not claim the box it wraps. `why`: what perception knows of it (a
    dropped mask), plain text.
    """

    id: str
    min: Vec3
    max: Vec3
    pixels: int
    area_m2: float
    columns: tuple[tuple[float, float, float, float, float], ...] = ()
    why: str = ""

    def to_json(self) -> dict:
        doc: dict[str, Any] = {"id": self.id, "min": list(self.min), "max": list(self.max),
                               "pixels": self.pixels, "area_m2": self.area_m2,
                               "columns": [list(c) for c in self.columns]}
        if self.why:
            doc["why"] = self.why
        return doc

    @classmethod
    def from_json(cls, doc: Any, origin: str = "", where: str = "unexplained") -> "Unexplained":
        doc = _obj(doc, origin, where)
        uid = check_id(_req(doc, "id", origin, f"{where}."), origin, f"{where}.id")   # shown in logs and the 3D view
        lo = _vec(_req(doc, "min", origin, f"{where}."), 3, origin, f"{where}.min")
        hi = _vec(_req(doc, "max", origin, f"{where}."), 3, origin, f"{where}.max")
        _box_bounds(lo, hi, origin, f"{where}.max")
        px = _req(doc, "pixels", origin, f"{where}.")
        if isinstance(px, bool) or not isinstance(px, int) or px < 1:
            raise FormatError(origin, f"{where}.pixels", f"expected a positive integer, got {px!r}")
        area = _num(_req(doc, "area_m2", origin, f"{where}."), origin, f"{where}.area_m2", nonneg=True)
        raw = doc.get("columns", [])
        if not isinstance(raw, list) or len(raw) > MAX_COLUMNS:
            raise FormatError(origin, f"{where}.columns", f"expected a list of at most {MAX_COLUMNS} "
                              f"[x0, x1, z0, z1, y], got {type(raw).__name__} of {len(raw) if isinstance(raw, list) else 1}")
        cols = tuple(_vec(c, 5, origin, f"{where}.columns[{i}]") for i, c in enumerate(raw))
        for i, c in enumerate(cols):
            if c[0] > c[1] or c[2] > c[3]:
                raise FormatError(origin, f"{where}.columns[{i}]", f"expected x0 <= x1 and z0 <= z1, got {list(c)!r}")
        why = doc.get("why", "")
        if not isinstance(why, str):
            raise FormatError(origin, f"{where}.why", f"expected a string, got {why!r}")
        return cls(uid, lo, hi, px, area, cols, why)  # type: ignore[arg-type]


def _unexplained_from_json(raw: Any, origin: str) -> tuple[Unexplained, ...] | None:
    """The optional `unexplained` list (None: the scene never looked; []: it looked, found none)."""
    if raw is None:
        return None
    if not isinstance(raw, list) or len(raw) > MAX_UNEXPLAINED:
        raise FormatError(origin, "unexplained", f"expected a list of at most {MAX_UNEXPLAINED} regions, "
                          f"got {type(raw).__name__}{f' of {len(raw)}' if isinstance(raw, list) else ''}")
    out = tuple(Unexplained.from_json(u, origin, f"unexplained[{i}]") for i, u in enumerate(raw))
    ids = [u.id for u in out]
    for i, u in enumerate(ids):
        if u in ids[:i]:
            raise FormatError(origin, f"unexplained[{i}].id", f"duplicated region id {u!r}")
    return out


@dataclass(frozen=True)
class Scene:
    """A shelf and the boxes in it, in the shelf frame."""

    shelf: Shelf
    boxes: tuple[Box, ...]
    camera: Camera | None = None
    source: Any = None
    # matter seen inside the shelf that no box explains; None: never looked (no depth, an old file)
    unexplained: tuple[Unexplained, ...] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "boxes", tuple(self.boxes))
        if self.unexplained is not None:
            object.__setattr__(self, "unexplained", tuple(self.unexplained))

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(b.id for b in self.boxes)

    def box(self, box_id: str) -> Box:
        for b in self.boxes:
            if b.id == box_id:
                return b
        raise KeyError(box_id)

    def require(self, box_id: str, origin: str = "") -> Box:
        """The box with this id, or a FormatError listing the ids there are."""
        try:
            return self.box(box_id)
        except KeyError:
            raise FormatError(origin, "target", f"unknown box id {box_id!r}; the scene has "
                              f"{', '.join(self.ids) or 'no boxes'}") from None

    def without(self, ids: Iterable[str]) -> "Scene":
        gone = set(ids)
        return replace(self, boxes=tuple(b for b in self.boxes if b.id not in gone))

    def with_boxes(self, boxes: Iterable[Box]) -> "Scene":
        return replace(self, boxes=tuple(boxes))

    @property
    def depth_known(self) -> bool:
        return all(b.depth_known for b in self.boxes)

    def hide_depths(self, placeholder: float | None = None) -> "Scene":
        """What a camera gives: front faces kept, depth unknown (placeholder depth)."""
        out = []
        for b in self.boxes:
            d = placeholder if placeholder is not None else b.size[1]
            out.append(replace(b.with_depth(d), depth_known=False))
        return self.with_boxes(out)

    def to_json(self) -> dict:
        doc: dict[str, Any] = {"format": SCENE_FORMAT, "shelf": self.shelf.to_json(),
                               "boxes": [b.to_json() for b in self.boxes]}
        if self.camera is not None:
            doc["camera"] = self.camera.to_json()
        if self.source is not None:
            doc["source"] = self.source
        if self.unexplained is not None:
            doc["unexplained"] = [u.to_json() for u in self.unexplained]
        return doc

    @classmethod
    def from_json(cls, doc: Any, origin: str = "") -> "Scene":
        doc = _obj(doc, origin, "scene")
        fmt = _req(doc, "format", origin)
        if fmt != SCENE_FORMAT:
            raise FormatError(origin, "format", f"expected {SCENE_FORMAT!r}, got {fmt!r}")
        shelf = Shelf.from_json(_req(doc, "shelf", origin), origin)
        raw = _req(doc, "boxes", origin)
        if not isinstance(raw, list):
            raise FormatError(origin, "boxes", f"expected a list, got {type(raw).__name__}")
        if len(raw) > MAX_BOXES:
            raise FormatError(origin, "boxes", f"{len(raw)} boxes; a scene holds at most {MAX_BOXES}")
        boxes = [Box.from_json(b, origin, f"boxes[{i}]") for i, b in enumerate(raw)]
        seen: set[str] = set()
        for b in boxes:
            if b.id in seen:
                raise FormatError(origin, f"boxes[id={b.id}].id", f"duplicated box id {b.id!r}")
            seen.add(b.id)
        camera = Camera.from_json(doc["camera"], origin, "camera") if doc.get("camera") is not None else None
        scene = cls(shelf, tuple(boxes), camera, doc.get("source"),
                    _unexplained_from_json(doc.get("unexplained"), origin))
        scene.check_bounds(origin)
        return scene

    def check_bounds(self, origin: str = "", tol: float = 0.04) -> None:
        """Refuse boxes that stand outside the shelf interior (beyond `tol`).

        Boxes may stick out of the open front (y < 0): that is how shelves look.
        `tol` (4 cm) is what a face measured to about 1 cm can be off by; less
        is a measurement to reconcile (planning repairs and reports it), not a
        format error.
        """
        s = self.shelf
        for b in self.boxes:
            cs = b.corners()
            xs = [c[0] for c in cs]
            ys = [c[1] for c in cs]
            zs = [c[2] for c in cs]
            fld = f"boxes[id={b.id}].position"
            if min(xs) < -s.width / 2 - tol or max(xs) > s.width / 2 + tol:
                raise FormatError(origin, fld, f"box {b.id!r} spans x {min(xs):.3f}..{max(xs):.3f} m, "
                                  f"outside the shelf width [-{s.width/2:.3f}, {s.width/2:.3f}]")
            if max(ys) > s.depth + tol:
                raise FormatError(origin, fld, f"box {b.id!r} reaches y={max(ys):.3f} m, behind the "
                                  f"back wall at y={s.depth:.3f}")
            if max(ys) < 0:
                raise FormatError(origin, fld, f"box {b.id!r} lies entirely in front of the shelf "
                                  f"(y up to {max(ys):.3f} m)")
            if min(zs) < -tol or max(zs) > s.height + tol:
                raise FormatError(origin, fld, f"box {b.id!r} spans z {min(zs):.3f}..{max(zs):.3f} m, "
                                  f"outside the shelf height [0, {s.height:.3f}]")

    @classmethod
    def load(cls, path: str | Path) -> "Scene":
        return cls.from_json(read_json(path), str(path))

    def save(self, path: str | Path) -> None:
        write_json(path, self.to_json())
