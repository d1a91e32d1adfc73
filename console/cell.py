"""A robot cell described in one TOML file (`shelfpick console --cell cell.toml`).

What the console needs to know about an installation, in one place instead of URL query strings:
the shelf interior, the camera (source, intrinsics and pose file), the segmenter and its weights,
the robot (URL, shelf-to-robot transform, timeouts) and the safety settings. Read and checked
completely before anything is opened: a wrong value is a `CellError`, one line naming the file,
the field and the value (exit 2). Relative paths are relative to the cell file. See docs/cli.md
"Cell file" and examples/cell.toml.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping
from urllib.parse import quote

from shelfpick.perception.errors import FormatError

from shelfpick.planning.cell_file import CELL_FORMAT
from shelfpick.planning.priors import PLANNING_KEYS

SEGMENTERS = ("auto", "depth", "photo", "yolo", "learned")
TIMEOUTS = ("connect_timeout", "ack_timeout", "step_timeout", "heartbeat", "heartbeat_timeout", "abort_timeout")
SECTIONS: dict[str, tuple[str, ...]] = {
    "shelf": ("width", "depth", "height"),
    "camera": ("source", "file"),
    "perception": ("segmenter", "weights", "catalogue"),
    "robot": ("url", "transform", "position", "orientation") + TIMEOUTS,
    "safety": ("samples", "seed", "workers", "host", "port", "db", "tolerance_displacement",
               "tolerance_rotation", "tolerance_match_radius", "allow_origins"),
    # the cell's stock and gripper as its sample worlds draw them, and its plan threshold (issue 32)
    "planning": PLANNING_KEYS,
}

# every number a robot spec may carry, in the cell file's [robot] section or a --robot URL's query: the
# one table both are checked against (robot_number), so neither accepts what the other refuses
ROBOT_NUMBERS: dict[str, tuple[float, float]] = {**{k: (1e-3, 3600.0) for k in TIMEOUTS},
                                                 "delay": (0.0, 600.0), "seed": (0.0, 2.0**63 - 1)}
SIM_OPTIONS = ("delay", "seed", "surprise")
TCP_OPTIONS = ("transform", "position", "orientation") + TIMEOUTS


class CellError(FormatError):
    """A cell file that is wrong: `cell.toml: robot.url: expected tcp://HOST:PORT or sim, got 'x'`."""


@dataclass(frozen=True)
class Cell:
    """One installation, as read from its cell file (paths resolved against the file's folder)."""

    path: str
    shelf: tuple[float, float, float] | None = None
    source: str | None = None
    camera_file: str | None = None
    segmenter: str = "auto"
    weights: str | None = None
    catalogue: bool = True
    robot: str | None = None                      # the robot spec open_robot takes, options included
    safety: Mapping[str, Any] = field(default_factory=dict)
    planning: Mapping[str, Any] = field(default_factory=dict)   # the [planning] section, checked

    def priors(self) -> Any:
        """planning.priors.CellPriors from the [planning] section (defaults where not given)."""
        from shelfpick.planning.priors import CellPriors

        return CellPriors(**self.planning)

    def source_spec(self) -> str | None:
        """The console's --source with the cell's camera file as its ?camera= option."""
        if self.source is None:
            return None
        if self.camera_file and not self.source.startswith("files:"):
            return f"{self.source}?camera={self.camera_file}"
        return self.source

    def tolerance(self) -> Any:
        """console.workflow.verify.Tolerance from the safety section (defaults where not given)."""
        from shelfpick.console.workflow.verify import Tolerance

        d = Tolerance()
        s = self.safety
        return Tolerance(s.get("tolerance_displacement", d.displacement), s.get("tolerance_rotation", d.rotation),
                         s.get("tolerance_match_radius", d.match_radius))


def read_cell(path: str | Path) -> Cell:
    """Parse and check a cell file completely; CellError (one line) on the first wrong value."""
    from shelfpick.planning.cell_file import read_cell_toml

    try:
        doc = read_cell_toml(path)
    except FormatError as exc:
        raise CellError(exc.origin, exc.field, exc.problem) from None
    return _cell(doc, str(path), Path(path).resolve().parent)


def robot_number(key: str, text: Any, origin: str, fld: str) -> float:
    """One number of a robot spec (a timeout, sim's delay or seed) checked against ROBOT_NUMBERS;
    CellError naming `origin` and `fld` otherwise. `text`: a URL's string or a TOML number."""
    lo, hi = ROBOT_NUMBERS[key]
    try:
        v = float(text) if isinstance(text, str) else (float(text) if isinstance(text, (int, float))
                                                       and not isinstance(text, bool) else math.nan)
    except (ValueError, OverflowError):
        v = math.nan
    if not (math.isfinite(v) and lo <= v <= hi):
        shown = text if not isinstance(text, str) or len(text) <= 40 else text[:40] + "..."
        raise CellError(origin, fld, f"expected a number in [{lo:g}, {hi:g}], got {shown!r}")
    return v


def check_robot_spec(spec: str, origin: str = "--robot") -> str:
    """A robot spec as `console.robot.drivers.open_robot` takes it (`sim[?delay=S&seed=N&surprise=0|1]` or
    `tcp://HOST:PORT[?options]`), checked completely before anything is opened: its shape (an IPv6
    host in brackets), known options only, every number within ROBOT_NUMBERS (the cell file's
    bounds). CellError, one line naming `origin` and the option; returns the spec stripped, its scheme
    written `tcp`."""
    from urllib.parse import parse_qs, urlsplit

    spec = spec.strip()
    if len(spec) > 4096 or not spec.isprintable():
        raise CellError(origin, "", f"expected sim or tcp://HOST:PORT (printable, at most 4096 characters), "
                                    f"got {ascii(spec[:60])}")
    base, _, query = spec.partition("?")
    try:
        q = parse_qs(query, keep_blank_values=True, strict_parsing=bool(query), max_num_fields=32)
        parts = urlsplit(spec)
        port = parts.port
    except ValueError as exc:
        raise CellError(origin, "", f"expected sim or tcp://HOST:PORT, got {spec!r} ({exc})") from None
    if base == "sim":
        allowed = SIM_OPTIONS
    elif parts.scheme == "tcp" and parts.hostname and port and parts.path in ("", "/"):
        allowed = TCP_OPTIONS
    else:
        raise CellError(origin, "", f"expected sim or tcp://HOST:PORT (a port 1-65535), got {spec!r}")
    for key, values in q.items():
        if key not in allowed:
            raise CellError(origin, key, f"unknown option (known: {', '.join(allowed)})")
        if len(values) != 1:
            raise CellError(origin, key, "given more than once")
        if key in ROBOT_NUMBERS:
            robot_number(key, values[0], origin, key)
    if q.get("surprise", ["0"])[0] not in ("0", "1"):
        raise CellError(origin, "surprise", f"expected 0 or 1, got {q['surprise'][0]!r}")
    if base != "sim":     # a scheme is case-blind (RFC 3986), as in the cell file: the drivers read tcp://
        spec = "tcp" + spec[len(parts.scheme):]
    return spec


def _cell(doc: Mapping[str, Any], origin: str, base: Path) -> Cell:
    unknown = sorted(set(doc) - set(SECTIONS) - {"format"})
    if unknown:
        raise CellError(origin, unknown[0], f"unknown section or key (known: format, {', '.join(SECTIONS)})")
    if doc.get("format", CELL_FORMAT) != CELL_FORMAT:
        raise CellError(origin, "format", f"expected {CELL_FORMAT!r}, got {doc['format']!r}")
    sec = {name: _section(doc, name, origin) for name in SECTIONS}
    shelf = None
    if sec["shelf"]:
        shelf = tuple(_number(sec["shelf"], "shelf", k, origin, lo=0.05, hi=20.0) for k in ("width", "depth", "height"))
    cam = sec["camera"]
    source = _string(cam, "camera", "source", origin) if "source" in cam else None
    if source is not None and not (source in ("demo", "realsense") or
                                   source.startswith(("demo:", "files:", "bag:"))):
        raise CellError(origin, "camera.source", f"expected demo, demo:NAME, files:DIR, realsense or bag:FILE, "
                                                 f"got {source!r}")
    if source is not None and source.startswith(("files:", "bag:")):
        kind, _, where = source.partition(":")
        source = f"{kind}:{_path(where, base, origin, 'camera.source')}"
    camera_file = _file(cam, "camera", "file", origin, base) if "file" in cam else None
    if camera_file is not None:
        from shelfpick.perception.scene import Camera

        Camera.load(camera_file)          # its own one-line FormatError names the camera file and field
    per = sec["perception"]
    segmenter = _string(per, "perception", "segmenter", origin) if "segmenter" in per else "auto"
    if segmenter not in SEGMENTERS:
        raise CellError(origin, "perception.segmenter", f"expected one of {', '.join(SEGMENTERS)}, got {segmenter!r}")
    weights = _file(per, "perception", "weights", origin, base) if "weights" in per else None
    if weights is not None and segmenter in ("depth", "photo"):
        raise CellError(origin, "perception.weights", f"weights are for the yolo or learned segmenter, "
                                                      f"not {segmenter!r}")
    catalogue = per.get("catalogue", True)
    if not isinstance(catalogue, bool):
        raise CellError(origin, "perception.catalogue", f"expected true or false, got {catalogue!r}")
    robot = _robot(sec["robot"], origin, base) if sec["robot"] else None
    return Cell(origin, shelf, source, camera_file, segmenter, weights, catalogue, robot,
                _safety(sec["safety"], origin, base), _planning(sec["planning"], origin))


def _section(doc: Mapping[str, Any], name: str, origin: str) -> dict[str, Any]:
    sec = doc.get(name, {})
    if not isinstance(sec, Mapping):
        raise CellError(origin, name, f"expected a table [{name}], got {sec!r}")
    unknown = sorted(set(sec) - set(SECTIONS[name]))
    if unknown:
        raise CellError(origin, f"{name}.{unknown[0]}", f"unknown key (known: {', '.join(SECTIONS[name])})")
    return dict(sec)


def _number(sec: Mapping[str, Any], name: str, key: str, origin: str, *, lo: float = 0.0,
            hi: float = math.inf, integer: bool = False) -> Any:
    v = sec.get(key)
    if key not in sec:
        raise CellError(origin, f"{name}.{key}", "missing required key")
    ok_type = isinstance(v, int) if integer else isinstance(v, (int, float))
    if isinstance(v, bool) or not ok_type or not (math.isfinite(v) and lo <= v <= hi):
        what = "an integer" if integer else "a number"
        raise CellError(origin, f"{name}.{key}", f"expected {what} in [{lo:g}, {hi:g}], got {v!r}")
    return int(v) if integer else float(v)


def _string(sec: Mapping[str, Any], name: str, key: str, origin: str) -> str:
    v = sec[key]
    if not isinstance(v, str) or not v.strip():
        raise CellError(origin, f"{name}.{key}", f"expected a non-empty string, got {v!r}")
    return v.strip()


def _path(value: str, base: Path, origin: str, fld: str, *, must_exist: bool = True) -> str:
    p = Path(value).expanduser()
    p = p if p.is_absolute() else base / p
    if must_exist and not p.exists():
        raise CellError(origin, fld, f"{value!r}: no such file or folder (looked at {p})")
    return str(p)


def _file(sec: Mapping[str, Any], name: str, key: str, origin: str, base: Path) -> str:
    path = _path(_string(sec, name, key, origin), base, origin, f"{name}.{key}")
    if not Path(path).is_file():
        raise CellError(origin, f"{name}.{key}", f"{sec[key]!r}: not a regular file")
    return path


def _vector(sec: Mapping[str, Any], key: str, n: int, origin: str) -> list[float]:
    v = sec[key]
    if (not isinstance(v, list) or len(v) != n
            or not all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in v)):
        raise CellError(origin, f"robot.{key}", f"expected a list of {n} numbers, got {v!r}")
    return [float(x) for x in v]


def _robot(sec: Mapping[str, Any], origin: str, base: Path) -> str:
    """The robot section as the spec `console.robot.drivers.open_robot` takes (checked here, named by field)."""
    url = _string(sec, "robot", "url", origin) if "url" in sec else None
    if url is None:
        raise CellError(origin, "robot.url", "missing required key (sim or tcp://HOST:PORT)")
    if url == "sim":
        extra = sorted(k for k in sec if k != "url")
        if extra:
            raise CellError(origin, f"robot.{extra[0]}", "only for a tcp:// robot (robot.url is 'sim')")
        return "sim"
    from urllib.parse import urlsplit

    try:
        parts = urlsplit(url)
        port = parts.port
    except ValueError:          # a bracket left open, a port out of range
        parts, port = urlsplit(""), None
    if parts.scheme != "tcp" or not parts.hostname or not port or parts.query or parts.path not in ("", "/"):
        raise CellError(origin, "robot.url", f"expected sim or tcp://HOST:PORT (options go in their own keys), "
                                             f"got {url!r}")
    opts: list[tuple[str, str]] = []
    if "transform" in sec:
        if "position" in sec or "orientation" in sec:
            raise CellError(origin, "robot.transform", "give a transform file or position/orientation, not both")
        tfile = _file(sec, "robot", "transform", origin, base)
        from shelfpick.robotsim.transform import Transform   # where it lives (via console.robot.tcp: a cycle)

        Transform.load(tfile)                 # its own one-line error names the transform file
        opts.append(("transform", tfile))
    elif "position" in sec or "orientation" in sec:
        pos = _vector(sec, "position", 3, origin) if "position" in sec else [0.0, 0.0, 0.0]
        quat = _vector(sec, "orientation", 4, origin) if "orientation" in sec else [1.0, 0.0, 0.0, 0.0]
        norm = math.sqrt(sum(c * c for c in quat))
        if abs(norm - 1.0) > 1e-3:
            raise CellError(origin, "robot.orientation", f"quaternion (w, x, y, z) is not unit length "
                                                         f"(|q|={norm:.4f}): {sec['orientation']!r}")
        opts += [("position", ",".join(repr(x) for x in pos)), ("orientation", ",".join(repr(x) for x in quat))]
    for key in TIMEOUTS:
        if key in sec:
            opts.append((key, repr(robot_number(key, sec[key], origin, f"robot.{key}"))))
    query = "&".join(f"{k}={quote(v, safe='/,.-_:')}" for k, v in opts)
    host = f"[{parts.hostname}]" if ":" in parts.hostname else parts.hostname   # an IPv6 address
    return f"tcp://{host}:{port}" + (f"?{query}" if query else "")


def _safety(sec: Mapping[str, Any], origin: str, base: Path) -> dict[str, Any]:
    from shelfpick.planning.cmd_plan import SAMPLES, SEEDS, WORKERS

    out: dict[str, Any] = {}
    for key, (lo, hi) in (("samples", SAMPLES), ("workers", WORKERS), ("port", (0, 65535)), ("seed", SEEDS)):
        if key in sec:
            out[key] = _number(sec, "safety", key, origin, lo=lo, hi=hi, integer=True)
    for key, lo, hi in (("tolerance_displacement", 1e-4, 1.0), ("tolerance_rotation", 0.1, 180.0),
                        ("tolerance_match_radius", 1e-3, 2.0)):
        if key in sec:
            out[key] = _number(sec, "safety", key, origin, lo=lo, hi=hi)
    if "host" in sec:
        out["host"] = _string(sec, "safety", "host", origin)
    if "db" in sec:
        db = _path(_string(sec, "safety", "db", origin), base, origin, "safety.db", must_exist=False)
        out["db"] = db
    if "allow_origins" in sec:
        out["allow_origins"] = _origins(sec["allow_origins"], origin)
    return out


def _origins(value: Any, origin: str) -> tuple[str, ...]:
    """safety.allow_origins: browser origins besides the console's own (console/web/origin_guard.py)."""
    from shelfpick.console.web.origin_guard import normalize_origin

    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise CellError(origin, "safety.allow_origins", f"expected a list of origins like "
                                                        f"[\"https://proxy.example:8443\"], got {value!r}")
    out = []
    for v in value:
        try:
            out.append(normalize_origin(v))
        except ValueError as exc:
            raise CellError(origin, "safety.allow_origins", f"{v!r}: {exc}") from None
    return tuple(out)


def _planning(sec: Mapping[str, Any], origin: str) -> dict[str, Any]:
    """The [planning] section as planning.priors.CellPriors' keyword arguments, checked there (the
    one check `shelfpick plan --cell` makes too)."""
    from shelfpick.planning.priors import section_kwargs

    try:
        return section_kwargs(sec, origin)
    except FormatError as exc:
        raise CellError(exc.origin, exc.field, exc.problem) from None


__all__ = ["Cell", "CellError", "CELL_FORMAT", "ROBOT_NUMBERS", "check_robot_spec", "read_cell", "robot_number"]
