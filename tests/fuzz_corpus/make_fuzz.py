"""The second bad-input corpus (issue 30): files, arguments, images, databases, URLs and outputs
built from the kinds an adversarial probe broke, made at run time in a scratch folder (FIFOs,
symlinks to devices, sparse files, SQLite archives and images whose header claims 30000 x 30000
pixels cannot live in git).

    python tests/fuzz_corpus/make_fuzz.py DIR        # writes the files into DIR, prints the count

Deterministic (no random draw). `build(tmp)` returns one `FuzzCase` per case: the command line
(`shelfpick ARGV...`) and what its one stderr line must say. Every case is bad input: the command
must exit 2 with that one line, no traceback, within 10 s and 1 GB (benchmarks/fuzz_cli.py runs
them all and counts; tests/test_fuzz_corpus.py runs a representative subset).
None of these is in cases.json (the first corpus): they are new.
"""
from __future__ import annotations

import json
import os
import shutil
import sqlite3
import struct
import sys
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import make_corpus as mc  # noqa: E402  (the good documents and images of the first corpus)

MIB = 1 << 20


@dataclass(frozen=True)
class FuzzCase:
    name: str          # kind-what: scene-, plan-, camera-, image-, arg-, url-, cell-, db-, out-
    argv: tuple[str, ...]
    says: str          # a piece of the one stderr line


def _w(path: Path, data: bytes | str | dict | list) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    if isinstance(data, (dict, list)):
        data = json.dumps(data)
    path.write_bytes(data.encode() if isinstance(data, str) else data)
    return path


def _png_header(w: int, h: int, colour: int = 2, depth: int = 8) -> bytes:
    """A few hundred bytes whose header claims w x h pixels (one short compressed row, IEND)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", w, h, depth, colour, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b"\0" * 4096))
            + chunk(b"IEND", b""))


def _zeros_deflate(units: int) -> bytes:
    """A raw deflate stream of 1 + 2064 * units zero bytes, built directly: one literal 0, then
    (length 258, distance 1) matches, 8 to a unit, in a fixed-Huffman block. 8 matches are 104 bits,
    a whole number of bytes, so the stream is one 13-byte pattern repeated (zlib would need minutes
    to compress a gigabyte of zeros)."""
    acc, n = 0, 0

    def code(value: int, count: int) -> None:       # a Huffman code: most significant bit first
        nonlocal acc, n
        for i in range(count - 1, -1, -1):
            acc |= ((value >> i) & 1) << n
            n += 1

    code(0b110, 3)                                  # BFINAL 1, BTYPE 01 (as bits 1, 1, 0)
    code(0x30, 8)                                   # literal 0
    for _ in range(16):
        code(0b11000101, 8)                         # length 258
        code(0, 5)                                  # distance 1
    code(0, 7)                                      # end of block
    two = acc.to_bytes((n + 7) // 8, "little")     # the stream for 2 units
    return two[:15] + two[2:15] * (units - 2) + two[15:] if units >= 2 else b""


def _png_full_of_zeros(w: int, h: int) -> bytes:
    """A real w x h RGB PNG, all black, every row present: decodes to w * h * 3 bytes. (1 + 3 w) h
    must be 1 more than a multiple of 2064 (`_zeros_deflate`)."""
    size = (1 + 3 * w) * h
    assert (size - 1) % 2064 == 0
    body = b"\x78\x01" + _zeros_deflate((size - 1) // 2064) + struct.pack(">I", ((size % 65521) << 16) | 1)

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", body) + chunk(b"IEND", b""))


def _jpeg_header(w: int, h: int) -> bytes:
    """SOI, a baseline SOF0 claiming w x h, EOI: a header and nothing to decode."""
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, h, w, 3) + b"\x01\x22\x00\x02\x11\x01\x03\x11\x01"
    return b"\xff\xd8" + sof + b"\xff\xd9"


def _bmp_header(w: int, h: int) -> bytes:
    info = struct.pack("<IiiHHIIiiII", 40, w, h, 1, 24, 0, 0, 2835, 2835, 0, 0)
    return b"BM" + struct.pack("<IHHI", 14 + 40 + 64, 0, 0, 54) + info + b"\0" * 64


def _npy(shape: tuple, descr: str = "<f4", body: bytes = b"\0" * 64) -> bytes:
    header = f"{{'descr': '{descr}', 'fortran_order': False, 'shape': {shape!r}, }}"
    header += " " * (63 - (10 + len(header)) % 64) + "\n"
    return b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header.encode() + body


def _sparse(path: Path, size: int) -> Path:
    with open(path, "wb") as f:
        f.truncate(size)
    return path


def _scene(**box: Any) -> dict:
    return mc.box(**box)


# ---------------------------------------------------------------- scenes and plans (files)
def scene_cases(t: Path, good: Path) -> list[FuzzCase]:
    out: list[FuzzCase] = []

    def sc(name: str, doc: Any, says: str, raw: bytes | None = None) -> None:
        p = _w(t / "scene" / f"{name}.json", raw if raw is not None else doc)
        out.append(FuzzCase(f"scene-{name}", ("plan", str(p), "--task", "clear", "--samples", "1"), says))

    bad_ids = {"id-newline": "a\nb", "id-cr": "a\rb", "id-tab": "a\tb", "id-ansi": "\x1b[31mred\x1b[0m",
               "id-osc-title": "\x1b]0;pwned\x07", "id-nul": "nul\x00", "id-del": "del\x7f", "id-c1": "c1\x85",
               "id-line-sep": "a\u2028b", "id-bidi": "\u202eevil", "id-zero-width": "a\u200bb",
               "id-65-chars": "x" * 65, "id-1mb": "x" * MIB, "id-leading-space": " a",
               "id-trailing-space": "a ", "id-only-space": " ", "id-bell": "\x07"}
    for name, bid in bad_ids.items():
        sc(name, _scene(id=bid), "boxes[0].id: a box id is 1-64 printable characters")
    sc("id-lone-surrogate", None, "boxes[0].id: a box id",
       raw=json.dumps(_scene(id="SURR")).replace("SURR", "\\udc80").encode())
    sc("id-surrogate-pair-half", None, "boxes[0].id: a box id",
       raw=json.dumps(_scene(id="SURR")).replace("SURR", "ok\\ud83d").encode())
    sc("id-object", _scene(id={"a": 1}), "boxes[0].id: expected a non-empty string")
    sc("id-list", _scene(id=["a"]), "boxes[0].id: expected a non-empty string")
    sc("id-null", _scene(id=None), "boxes[0].id: expected a non-empty string")
    for name, shelf, field in (("shelf-1e300", {"width": 1e300, "depth": 0.3, "height": 1.6}, "shelf.width"),
                               ("shelf-1e-300", {"width": 1.0, "depth": 1e-300, "height": 1.6}, "shelf.depth"),
                               ("shelf-1cm", {"width": 1.0, "depth": 0.3, "height": 0.01}, "shelf.height"),
                               ("shelf-1km", {"width": 1000.0, "depth": 0.3, "height": 1.6}, "shelf.width"),
                               ("shelf-huge-int", {"width": 10**19, "depth": 0.3, "height": 1.6}, "shelf.width")):
        sc(name, mc.scene(shelf=shelf), f"{field}: must be within [0.05, 20] m")
    for name, size, i in (("size-1e-12", [1e-12, 0.2, 0.2], 0), ("size-1mm", [0.2, 0.001, 0.2], 1),
                          ("size-100m", [0.2, 0.2, 100.0], 2), ("size-1e300", [1e300, 0.2, 0.2], 0),
                          ("size-denormal", [0.2, 5e-324, 0.2], 1)):
        sc(name, _scene(size=size), f"boxes[id=a].size[{i}]: must be within [0.01, 5] m")
    sc("mass-1e9", _scene(mass=1e9), "boxes[id=a].mass: must be within")
    sc("mass-1e-9", _scene(mass=1e-9), "boxes[id=a].mass: must be within")
    sc("position-1e300", _scene(position=[1e300, 0.12, 0.1]), "boxes[id=a].position: box 'a' spans x")
    cam_far = mc.camera(position=[0.0, -1e300, 0.8])
    sc("camera-1e300-away", mc.scene(camera=cam_far), "camera.pose.position[1]: must be within [-50, 50] m")
    sc("camera-fx-1e300", mc.scene(camera=mc.camera(fx=1e300)), "camera.fx: must be within")
    sc("camera-width-30000", mc.scene(camera=mc.camera(width=30000)), "camera.width: must be at most 12000 px")
    sc("camera-depth-scale-1e6", mc.scene(camera=mc.camera(depth_scale=1e6)), "camera.depth_scale: must be within")
    sc("camera-cx-1e300", mc.scene(camera=mc.camera(cx=1e300)), "camera.cx: must be within")
    return out


def plan_cases(t: Path, good: Path) -> list[FuzzCase]:
    out: list[FuzzCase] = []

    def pl(name: str, doc: Any, says: str) -> None:
        p = _w(t / "plan" / f"{name}.json", doc)
        out.append(FuzzCase(f"plan-{name}", ("simulate", str(good / "scene.json"), str(p)), says))

    pred = lambda **k: [{"box": "a", **k}]  # noqa: E731
    pl("safe-risk-1", mc.plan(predicted=pred(collapse_prob=1.0)), "safe: true, but step 1 ('a') has predicted risk 1")
    pl("safe-collision-half", mc.plan(predicted=pred(collision_prob=0.5)), "safe: true, but step 1")
    pl("safe-above-threshold", mc.plan(predicted=pred(collapse_prob=0.2), provenance={"risk": 0.1}),
       "safe: true, but step 1")
    pl("provenance-risk-2", mc.plan(provenance={"risk": 2}), "provenance.risk: expected a probability")
    pl("provenance-risk-string", mc.plan(provenance={"risk": "low"}), "provenance.risk: expected a probability")
    pl("collapse-1.5", mc.plan(predicted=pred(collapse_prob=1.5)), "predicted[0].collapse_prob")
    pl("collision-negative", mc.plan(predicted=pred(collision_prob=-0.1)), "predicted[0].collision_prob")
    pl("target-newline", mc.plan(target="a\n", sequence=["a\n"]), "a box id is 1-64 printable")
    pl("sequence-ansi", mc.plan(task="clear", target=None, sequence=["a", "\x1b[2Jb"]), "sequence[1]: a box id")
    pl("sequence-nul", mc.plan(task="clear", target=None, sequence=["\x00"]), "sequence[0]: a box id")
    pl("predicted-box-bidi", mc.plan(predicted=[{"box": "\u202ea"}]), "predicted[0].box: a box id")
    pl("moved-ansi", mc.plan(predicted=pred(moved=["\x1b[1mb"])), "predicted[0].moved[0]: a box id")
    pl("sequence-65-chars", mc.plan(task="clear", target=None, sequence=["y" * 65]), "sequence[0]: a box id")
    pl("sequence-10000-unknown", mc.plan(task="clear", target=None, sequence=[f"z{i}" for i in range(10000)]),
       "sequence[0]: unknown box id 'z0'")
    pl("predicted-strings", mc.plan(predicted=["a"]), "predicted[0]: expected an object")
    return out


def camera_cases(t: Path, good: Path) -> list[FuzzCase]:
    out: list[FuzzCase] = []
    base = ["perceive", "--rgb", str(good / "rgb.png"), "--depth", str(good / "depth.png")]

    def cam(name: str, doc: Any, says: str) -> None:
        p = _w(t / "camera" / f"{name}.json", doc)
        out.append(FuzzCase(f"camera-{name}", (*base, "--camera", str(p), "--out", str(t / "out" / "s.json")), says))

    cam("width-30000", mc.camera(width=30000, height=30000), "width: must be at most 12000 px")
    cam("height-12001", mc.camera(height=12001), "height: must be at most 12000 px")
    cam("fx-1e300", mc.camera(fx=1e300), "fx: must be within [1, 1e+06] px")
    cam("fy-0.1", mc.camera(fy=0.1), "fy: must be within [1, 1e+06] px")
    cam("cx-1e300", mc.camera(cx=1e300), "cx: must be within")
    cam("cy-minus-1e9", mc.camera(cy=-1e9), "cy: must be within")
    cam("depth-scale-1e6", mc.camera(depth_scale=1e6), "depth_scale: must be within")
    cam("depth-scale-1e-300", mc.camera(depth_scale=1e-300), "depth_scale: must be within")
    cam("position-1e300", mc.camera(position=[0.0, -1e300, 0.8]), "pose.position[1]: must be within [-50, 50] m")
    cam("position-1km", mc.camera(position=[1000.0, -1.0, 0.8]), "pose.position[0]: must be within [-50, 50] m")
    return out


# ---------------------------------------------------------------- images and arrays
def image_cases(t: Path, good: Path) -> list[FuzzCase]:
    out: list[FuzzCase] = []
    d = t / "image"
    d.mkdir(parents=True, exist_ok=True)
    cam = str(good / "camera.json")
    o = str(t / "out" / "s.json")

    def rgb(name: str, path: Path, says: str) -> None:
        out.append(FuzzCase(f"image-rgb-{name}", ("perceive", "--rgb", str(path), "--depth", str(good / "depth.png"),
                                                  "--camera", cam, "--out", o), says))

    def depth(name: str, path: Path, says: str) -> None:
        out.append(FuzzCase(f"image-depth-{name}", ("perceive", "--rgb", str(good / "rgb.png"), "--depth", str(path),
                                                    "--camera", cam, "--out", o), says))

    rgb("png-30000x30000", _w(d / "p30000.png", _png_header(30000, 30000)), "image of more than 40000000 pixels")
    rgb("png-20000x2500", _w(d / "p20000.png", _png_header(20000, 2500)), "image is 20000x2500 px")
    # a whole 20000 x 19729 image of zeros in 7.5 MB: 1.2 GB once decoded (the old code decoded it)
    rgb("png-full-1.2gb", _w(d / "full.png", _png_full_of_zeros(20000, 19729)),
        "full.png: image of more than 40000000 pixels")
    rgb("png-12001x16", _w(d / "p12001.png", _png_header(12001, 16)), "image is 12001x16 px")
    rgb("png-1x40000001", _w(d / "ptall.png", _png_header(1, 40_000_001)), "pixels")
    rgb("png-16bit-huge", _w(d / "p16.png", _png_header(15000, 15000, 2, 16)), "p16.png: image")
    rgb("png-max-int", _w(d / "pmax.png", _png_header(2**31 - 1, 2**31 - 1)), "pmax.png: image")
    rgb("jpeg-65000", _w(d / "j65000.jpg", _jpeg_header(65000, 65000)), "pixels")
    rgb("jpeg-12000x12000", _w(d / "j12000.jpg", _jpeg_header(12000, 12000)), "image is 12000x12000 px")
    rgb("bmp-100000", _w(d / "b.bmp", _bmp_header(100000, 100000)), "b.bmp")
    rgb("gif-garbage", _w(d / "g.gif", b"GIF89a" + struct.pack("<HH", 65535, 65535) + b"\0" * 32), "g.gif")
    (d / "zero.png").symlink_to("/dev/zero")
    rgb("symlink-dev-zero", d / "zero.png", "not a regular file")
    os.mkfifo(d / "fifo.png")
    rgb("fifo", d / "fifo.png", "not a regular file")
    (d / "folder.png").mkdir()
    rgb("folder", d / "folder.png", "not a regular file")
    rgb("sparse-300mb", _sparse(d / "sparse.png", 300 * MIB), "an image file is at most")
    rgb("png-header-only", _w(d / "hdr.png", _png_header(64, 48)[:33]), "truncated PNG")
    rgb("png-bad-idat", _w(d / "idat.png", _png_header(64, 48).replace(zlib.compress(b"\0" * 4096),
                                                                          b"\x78\x9c" + b"\xff" * 30)),
        "idat.png: not a readable image")
    depth("png-30000x30000", _w(d / "d30000.png", _png_header(30000, 30000, 0, 16)), "pixels")
    depth("png-13000x16", _w(d / "d13000.png", _png_header(13000, 16, 0, 16)), "image is 13000x16 px")
    (d / "dzero.png").symlink_to("/dev/zero")
    depth("symlink-dev-zero", d / "dzero.png", "not a regular file")
    depth("npy-100000-square", _w(d / "big.npy", _npy((100000, 100000))), "depth array is 100000x100000")
    depth("npy-13000x1", _w(d / "wide.npy", _npy((1, 13000))), "depth array is 13000x1")
    depth("npy-3d-huge", _w(d / "cube.npy", _npy((10000, 10000, 10000))), "depth array must be 2-D")
    depth("npy-unicode-1e5", _w(d / "ustr.npy", _npy((4, 4), "<U100000")), "depth array must be numbers")
    depth("npy-void-1e6", _w(d / "void.npy", _npy((4, 4), "|V1000000")), "depth array must be numbers")
    depth("npy-bad-header", _w(d / "hdr.npy", b"\x93NUMPY\x01\x00\xff\xff{'descr'"), "not a readable .npy")
    depth("npy-sparse-300mb", _sparse(d / "sparse.npy", 300 * MIB), "an image file is at most")
    (d / "zero.npy").symlink_to("/dev/zero")
    depth("npy-dev-zero", d / "zero.npy", "not a regular file")
    # masks beside an RGB: a huge masks.png
    m = d / "masks"
    m.mkdir()
    shutil.copy(good / "rgb.png", m / "rgb.png")
    _w(m / "masks.png", _png_header(30000, 30000, 0, 16))
    _w(m / "masks.json", {"1": "a"})
    rgb("masks-png-30000", m / "rgb.png", "masks.png")
    return out


# ---------------------------------------------------------------- command-line arguments
def arg_cases(t: Path, good: Path) -> list[FuzzCase]:
    s = str(good / "scene.json")
    plan = ("plan", s, "--task", "clear")
    out = [
        FuzzCase("arg-plan-samples-1e9", (*plan, "--samples", "1000000000"), "--samples: expected a positive integer"),
        FuzzCase("arg-plan-samples-0", (*plan, "--samples", "0"), "--samples"),
        FuzzCase("arg-plan-samples-negative", (*plan, "--samples", "-5"), "--samples"),
        FuzzCase("arg-plan-samples-float", (*plan, "--samples", "1e9"), "argument --samples: invalid int value"),
        FuzzCase("arg-plan-samples-huge", (*plan, "--samples", "9" * 400), "--samples"),
        FuzzCase("arg-plan-verify-1e9", (*plan, "--verify", "1000000000"), "--verify"),
        FuzzCase("arg-plan-workers-1e6", (*plan, "--workers", "1000000"), "--workers"),
        FuzzCase("arg-plan-workers-0", (*plan, "--workers", "0"), "--workers"),
        FuzzCase("arg-plan-seed-negative", (*plan, "--seed", "-1"), "--seed"),
        FuzzCase("arg-plan-seed-2-64", (*plan, "--seed", str(2**64)), "--seed"),
        FuzzCase("arg-plan-budget-1e308", (*plan, "--budget", "1e308"), "--budget"),
        FuzzCase("arg-plan-budget-nan", (*plan, "--budget", "nan"), "--budget"),
        FuzzCase("arg-plan-budget-inf", (*plan, "--budget", "inf"), "--budget"),
        FuzzCase("arg-plan-budget-negative", (*plan, "--budget", "-1"), "--budget"),
        FuzzCase("arg-plan-risk-nan", (*plan, "--risk", "nan"), "--risk"),
        FuzzCase("arg-plan-risk-2", (*plan, "--risk", "2"), "--risk"),
        FuzzCase("arg-plan-face-error-1", (*plan, "--face-error", "1"), "--face-error"),
        FuzzCase("arg-plan-face-error-nan", (*plan, "--face-error", "nan"), "--face-error"),
        FuzzCase("arg-plan-target-ansi", ("plan", s, "--target", "\x1b[31ma"), "unknown box id '\\x1b[31ma'"),
        FuzzCase("arg-plan-target-newline", ("plan", s, "--target", "a\nb"), "unknown box id 'a\\nb'"),
        FuzzCase("arg-plan-task-bogus", ("plan", s, "--task", "juggle"), "argument --task: invalid choice"),
        FuzzCase("arg-plan-unknown-option", (*plan, "--frobnicate"), "unrecognized arguments"),
        FuzzCase("arg-simulate-seed-negative", ("simulate", s, str(good / "plan.json"), "--seed", "-3"), "--seed"),
        FuzzCase("arg-perceive-shelf-1e300", ("perceive", "--rgb", str(good / "rgb.png"), "--depth",
                                              str(good / "depth.png"), "--camera", str(good / "camera.json"),
                                              "--out", str(t / "out" / "s.json"), "--shelf", "1e300", "0.3", "1.6"),
                 "--shelf: must be within [0.05, 20] m"),
        FuzzCase("arg-perceive-front-distance-1e9", ("perceive", "--rgb", str(good / "rgb.png"), "--camera",
                                                     str(good / "camera.json"), "--out", str(t / "out" / "s.json"),
                                                     "--front-distance", "1e9"), "--front-distance: must be within"),
        FuzzCase("arg-perceive-box-size-1e-12", ("perceive", "--rgb", str(good / "rgb.png"), "--camera",
                                                 str(good / "camera.json"), "--out", str(t / "out" / "s.json"),
                                                 "--box-size", "1e-12", "0.2"), "--box-size: must be within"),
        FuzzCase("arg-replay-id-2-70", ("replay", str(2**70), "--html", str(t / "out" / "r.html"), "--db",
                                        str(t / "db" / "good.db")), "id: expected a session id"),
        FuzzCase("arg-replay-id-0", ("replay", "0", "--html", str(t / "out" / "r.html"), "--db",
                                     str(t / "db" / "good.db")), "id: expected a session id"),
        FuzzCase("arg-replay-id-negative", ("replay", "-7", "--html", str(t / "out" / "r.html"), "--db",
                                            str(t / "db" / "good.db")), "id: expected a session id"),
        FuzzCase("arg-replay-id-text", ("replay", "one", "--html", str(t / "out" / "r.html")),
                 "argument id: invalid int value"),
    ]
    con = ("console", "--port", "0", "--no-capture", "--db", str(t / "out" / "console.db"))
    out += [
        FuzzCase("arg-console-samples-1e9", (*con, "--samples", "1000000000"), "--samples: must be from 1 to 1000"),
        FuzzCase("arg-console-samples-float", (*con, "--samples", "1e9"), "argument --samples: invalid int value"),
        FuzzCase("arg-console-samples-0", (*con, "--samples", "0"), "--samples: must be from 1 to 1000"),
        FuzzCase("arg-console-workers-1e5", (*con, "--workers", "100000"), "--workers: must be from 1 to 256"),
        FuzzCase("arg-console-seed-negative", (*con, "--seed", "-5"), "--seed: must be from 0"),
        FuzzCase("arg-console-seed-2-64", (*con, "--seed", str(2**64)), "--seed: must be from 0"),
    ]
    return out


# ---------------------------------------------------------------- robot URLs
def url_cases(t: Path, good: Path) -> list[FuzzCase]:
    con = ("console", "--port", "0", "--no-capture", "--db", str(t / "out" / "console.db"), "--robot")
    urls = {
        "bracket-open": ("tcp://[::1:9000", "expected sim or tcp://HOST:PORT"),
        "bracket-close": ("tcp://::1]:9000", "expected sim or tcp://HOST:PORT"),
        "heartbeat-0": ("tcp://127.0.0.1:9000?heartbeat=0", "heartbeat: expected a number in [0.001, 3600]"),
        "step-timeout-1e308": ("tcp://127.0.0.1:9000?step_timeout=1e308", "step_timeout: expected a number"),
        "ack-timeout-nan": ("tcp://127.0.0.1:9000?ack_timeout=nan", "ack_timeout: expected a number"),
        "connect-timeout-inf": ("tcp://127.0.0.1:9000?connect_timeout=inf", "connect_timeout: expected a number"),
        "abort-timeout-negative": ("tcp://127.0.0.1:9000?abort_timeout=-1", "abort_timeout: expected a number"),
        "heartbeat-timeout-text": ("tcp://127.0.0.1:9000?heartbeat_timeout=soon", "heartbeat_timeout: expected"),
        "timeout-twice": ("tcp://127.0.0.1:9000?heartbeat=1&heartbeat=2", "heartbeat: given more than once"),
        "unknown-option": ("tcp://127.0.0.1:9000?speed=11", "speed: unknown option"),
        "port-0": ("tcp://127.0.0.1:0", "expected sim or tcp://HOST:PORT"),
        "port-99999": ("tcp://127.0.0.1:99999", "expected sim or tcp://HOST:PORT"),
        "port-text": ("tcp://127.0.0.1:http", "expected sim or tcp://HOST:PORT"),
        "no-port": ("tcp://127.0.0.1", "expected sim or tcp://HOST:PORT"),
        "no-host": ("tcp://:9000", "expected sim or tcp://HOST:PORT"),
        "http": ("http://127.0.0.1:9000", "expected sim or tcp://HOST:PORT"),
        "path": ("tcp://127.0.0.1:9000/robot", "expected sim or tcp://HOST:PORT"),
        "sim-delay-1e308": ("sim?delay=1e308", "delay: expected a number in [0, 600]"),
        "sim-delay-negative": ("sim?delay=-1", "delay: expected a number"),
        "sim-delay-nan": ("sim?delay=nan", "delay: expected a number"),
        "sim-seed-negative": ("sim?seed=-1", "seed: expected a number"),
        "sim-seed-1e30": ("sim?seed=1e30", "seed: expected a number"),
        "sim-surprise-2": ("sim?surprise=2", "surprise: expected 0 or 1"),
        "sim-unknown": ("sim?transform=x.json", "transform: unknown option"),
        "sim-bad-query": ("sim?delay", "expected sim or tcp://HOST:PORT"),
        "ansi": ("sim\x1b[2J", "printable"),
        "newline": ("tcp://127.0.0.1:9000\nheartbeat=0", "printable"),
        "long-10000": ("tcp://" + "a" * 10000 + ":9000", "at most 4096 characters"),
        "empty": ("", "expected sim or tcp://HOST:PORT"),
        "many-fields": ("sim?" + "&".join(f"k{i}=1" for i in range(100)), "expected sim or tcp://HOST:PORT"),
    }
    return [FuzzCase(f"url-{name}", (*con, url), says) for name, (url, says) in urls.items()]


# ---------------------------------------------------------------- cell files
def cell_cases(t: Path, good: Path) -> list[FuzzCase]:
    d = t / "cell"
    d.mkdir(parents=True, exist_ok=True)
    out: list[FuzzCase] = []

    def cell(name: str, path: Path, says: str) -> None:
        out.append(FuzzCase(f"cell-{name}", ("console", "--port", "0", "--no-capture", "--db",
                                             str(t / "out" / "console.db"), "--cell", str(path)), says))

    (d / "zero.toml").symlink_to("/dev/zero")
    cell("symlink-dev-zero", d / "zero.toml", "not a regular file")
    os.mkfifo(d / "fifo.toml")
    cell("fifo", d / "fifo.toml", "not a regular file")
    (d / "folder.toml").mkdir()
    cell("folder", d / "folder.toml", "not a regular file")
    cell("sparse-2mb", _sparse(d / "big.toml", 2 * MIB), "a cell file is at most")
    cell("not-utf8", _w(d / "latin.toml", b"[shelf]\nwidth = 1.0 # \xe9\n"), "cannot read the cell file")
    cell("not-toml", _w(d / "bad.toml", "[shelf\nwidth = 1"), "not valid TOML")
    toml = {
        "heartbeat-0": ('[robot]\nurl = "tcp://127.0.0.1:9000"\nheartbeat = 0\n', "robot.heartbeat"),
        "step-timeout-1e308": ('[robot]\nurl = "tcp://127.0.0.1:9000"\nstep_timeout = 1e308\n', "robot.step_timeout"),
        "step-timeout-inf": ('[robot]\nurl = "tcp://127.0.0.1:9000"\nstep_timeout = inf\n', "robot.step_timeout"),
        "url-bracket-open": ('[robot]\nurl = "tcp://[::1:9000"\n', "robot.url"),
        "url-query": ('[robot]\nurl = "tcp://127.0.0.1:9000?heartbeat=0"\n', "robot.url"),
        "samples-1e9": ("[safety]\nsamples = 1000000000\n", "safety.samples"),
        "samples-float": ("[safety]\nsamples = 1e9\n", "safety.samples"),
        "workers-0": ("[safety]\nworkers = 0\n", "safety.workers"),
        "seed-negative": ("[safety]\nseed = -1\n", "safety.seed"),
        "shelf-1e300": ("[shelf]\nwidth = 1e300\ndepth = 0.3\nheight = 1.6\n", "shelf.width"),
        "shelf-nan": ("[shelf]\nwidth = nan\ndepth = 0.3\nheight = 1.6\n", "shelf.width"),
        "unknown-section": ("[rocket]\nthrust = 1\n", "rocket: unknown section"),
        "segmenter-ansi": ('[perception]\nsegmenter = "\\u001b[2J"\n', "perception.segmenter"),
    }
    for name, (text, says) in toml.items():
        cell(name, _w(d / f"{name}.toml", text), says)
    return out + plan_cell_cases(d, good)


def plan_cell_cases(d: Path, good: Path) -> list[FuzzCase]:
    """`shelfpick plan --cell`: the special files above, and wrong [planning] values (exit 2 before
    any physics is built; the clear task needs no target)."""
    def case(name: str, path: Path, says: str) -> FuzzCase:
        return FuzzCase(f"cell-plan-{name}", ("plan", str(good / "scene.json"), "--task", "clear",
                                              "--samples", "1", "--cell", str(path)), says)

    texts = {
        "mass-reversed": ("[planning]\nmass_kg = [3.0, 1.0]\n", "planning.mass_kg"),
        "mass-nan": ("[planning]\nmass_kg = [nan, 1.0]\n", "planning.mass_kg"),
        "friction-1e308": ("[planning]\nfriction = [0.5, 1e308]\n", "planning.friction"),
        "mode-unknown": ('[planning]\npull_modes = ["fly"]\n', "planning.pull_modes"),
        "mode-empty": ("[planning]\npull_modes = []\n", "planning.pull_modes"),
        "risk-zero": ("[planning]\nmax_plan_risk = 0\n", "planning.max_plan_risk"),
        "key-unknown": ("[planning]\ngravity = 1.6\n", "planning.gravity"),
    }
    out = [case(name, _w(d / f"plan-{name}.toml", text), says) for name, (text, says) in texts.items()]
    out += [case("symlink-dev-zero", d / "zero.toml", "not a regular file"),
            case("fifo", d / "fifo.toml", "not a regular file"),
            case("sparse-2mb", d / "big.toml", "bytes"),
            case("not-toml", d / "bad.toml", "not valid TOML"),
            case("missing", d / "nowhere.toml", "not found")]
    return out


# ---------------------------------------------------------------- session databases
def _base_db(d: Path) -> tuple[Path, int]:
    """One real session (render, plans with a physics preview, decisions, robot events)."""
    sys.path.insert(0, str(HERE.parent / "console"))
    from session_fixture import make_session

    db = d / "good.db"
    sid, _ = make_session(db)
    return db, sid


def _damaged(d: Path, base: Path, name: str, sql: str, args: tuple = ()) -> Path:
    db = d / f"{name}.db"
    shutil.copy(base, db)
    con = sqlite3.connect(db)
    con.execute(sql, args)
    con.commit()
    con.close()
    return db


def db_cases(t: Path, good: Path) -> list[FuzzCase]:
    d = t / "db"
    d.mkdir(parents=True, exist_ok=True)
    base, sid = _base_db(d)
    deep = "[" * 100_000 + "]" * 100_000
    html = str(t / "out" / "r.html")
    out: list[FuzzCase] = []
    damage = {
        "plan-not-json": ("UPDATE plans SET plan='not json'", (), "cannot be read"),
        "plan-deep": ("UPDATE plans SET plan=?", (deep,), "nested too deep"),
        "plan-list": ("UPDATE plans SET plan='[1, 2]'", (), "plan: expected an object"),
        "plan-ansi-id": ("UPDATE plans SET plan=?", (json.dumps(mc.plan(target="\x1b[2J", sequence=["\x1b[2J"])),),
                         "a box id"),
        "scene-not-json": ("UPDATE scenes SET scene='{'", (), "cannot be read"),
        "scene-deep": ("UPDATE scenes SET scene=?", (deep,), "nested too deep"),
        "scene-ansi-id": ("UPDATE scenes SET scene=?", (json.dumps(_scene(id="\x1b]0;x\x07")),), "a box id"),
        "scene-1e300-shelf": ("UPDATE scenes SET scene=?",
                              (json.dumps(mc.scene(shelf={"width": 1e300, "depth": 0.3, "height": 1.6})),),
                              "shelf.width: must be within"),
        "detail-not-json": ("UPDATE robot_events SET detail='nope'", (), "cannot be read"),
        "detail-deep": ("UPDATE robot_events SET detail=?", (deep,), "nested too deep"),
        "outcome-not-json": ("UPDATE outcomes SET outcome='{]'", (), "cannot be read"),
        "preview-deep": ("UPDATE plans SET preview=?", (deep,), "nested too deep"),
        "perception-not-json": ("UPDATE scenes SET perception='x'", (), "cannot be read"),
        "schema-999": ("UPDATE meta SET value='999' WHERE key='schema'", (), "is newer than this shelfpick"),
        "rgb-30000": ("UPDATE captures SET rgb=?", ("FILE",), "pixels"),
    }
    for name, (sql, args, says) in damage.items():
        db = _damaged(d, base, name, sql, args)
        if name == "rgb-30000":        # a capture image inside the store whose header claims 30000 x 30000
            shutil.copytree(base.with_name(base.name + ".files"), db.with_name(db.name + ".files"))
            _w(db.with_name(db.name + ".files") / str(sid) / "rgb.png", _png_header(30000, 30000))
            con = sqlite3.connect(db)
            for col in ("rgb", "depth", "camera", "masks", "overlay"):     # the copy's own files
                con.execute(f"UPDATE captures SET {col}=replace({col}, ?, ?)", (f"{base.name}.files",
                                                                                 f"{db.name}.files"))
            con.execute("UPDATE captures SET rgb=?", (f"{db.name}.files/{sid}/rgb.png",))
            con.commit()
            con.close()
        out.append(FuzzCase(f"db-replay-{name}", ("replay", str(sid), "--html", html, "--db", str(db)), says))
    for name in ("plan-not-json", "plan-deep", "detail-not-json", "detail-deep"):
        db = d / f"{name}.db"
        out.append(FuzzCase(f"db-stats-{name}", ("sessions", "--stats", "--db", str(db)),
                            "cannot be read" if "json" in name else "nested too deep"))
    _w(d / "text.db", "hello, not sqlite\n")
    _w(d / "empty.db", b"")
    os.mkfifo(d / "fifo.db")
    (d / "zero.db").symlink_to("/dev/zero")
    for name, says in (("text", "not a shelfpick session database"), ("empty", "not a shelfpick session database"),
                       ("fifo", "no session database here"), ("zero", "no session database here")):
        out.append(FuzzCase(f"db-sessions-{name}", ("sessions", "--db", str(d / f"{name}.db")), says))
    out.append(FuzzCase("db-replay-missing-id", ("replay", "99", "--html", html, "--db", str(base)),
                        "no session with id 99"))
    return out


# ---------------------------------------------------------------- outputs onto what is no file
def out_cases(t: Path, good: Path) -> list[FuzzCase]:
    d = t / "outs"
    d.mkdir(parents=True, exist_ok=True)
    os.mkfifo(d / "fifo")
    (d / "folder").mkdir()
    (d / "to_fifo").symlink_to(d / "fifo")
    (d / "to_folder").symlink_to(d / "folder")
    (d / "to_nothing").symlink_to(d / "nothing-here")
    (d / "to_dev_zero").symlink_to("/dev/zero")
    s, p = str(good / "scene.json"), str(good / "plan.json")
    perceive = ("perceive", "--rgb", str(good / "rgb.png"), "--depth", str(good / "depth.png"), "--camera",
                str(good / "camera.json"))
    out: list[FuzzCase] = []
    for target, says in (("fifo", "a FIFO"), ("folder", "a folder"), ("to_fifo", "a FIFO"),
                         ("to_folder", "a folder"), ("to_nothing", "a symlink to nothing"),
                         ("to_dev_zero", "a device")):
        path = str(d / target)
        out.append(FuzzCase(f"out-plan-{target}", ("plan", s, "--task", "clear", "--samples", "1", "--out", path),
                            f"--out: {says}"))
        out.append(FuzzCase(f"out-simulate-{target}", ("simulate", s, p, "--out", path), f"--out: {says}"))
        out.append(FuzzCase(f"out-perceive-{target}", (*perceive, "--out", path), f"--out: {says}"))
    out += [
        FuzzCase("out-perceive-overlay-fifo", (*perceive, "--out", str(t / "out" / "s.json"), "--overlay",
                                               str(d / "fifo")), "--overlay: a FIFO"),
        FuzzCase("out-perceive-masks-folder", (*perceive, "--out", str(t / "out" / "s.json"), "--masks",
                                               str(d / "folder")), "--masks: a folder"),
        FuzzCase("out-perceive-report-fifo", (*perceive, "--out", str(t / "out" / "s.json"), "--report",
                                              str(d / "to_fifo")), "--report: a FIFO"),
        FuzzCase("out-calibrate-board-fifo", ("calibrate", "--write-board", str(d / "fifo")), "--write-board: a FIFO"),
        FuzzCase("out-replay-html-fifo", ("replay", "1", "--html", str(d / "fifo"), "--db", str(t / "db" / "good.db")),
                 "--html: a FIFO"),
        FuzzCase("out-replay-html-folder", ("replay", "1", "--html", str(d / "folder"), "--db",
                                            str(t / "db" / "good.db")), "--html: a folder"),
    ]
    return out


KINDS = (scene_cases, plan_cases, camera_cases, image_cases, arg_cases, url_cases, cell_cases, db_cases, out_cases)


def build(tmp: Path) -> list[FuzzCase]:
    """Write every case's files under `tmp` (a fresh folder) and return the cases, in a fixed order."""
    tmp.mkdir(parents=True, exist_ok=True)
    good = tmp / "good"
    mc.write_good(good)
    (tmp / "out").mkdir(exist_ok=True)
    cases = [c for kind in KINDS for c in kind(tmp, good)]
    names = [c.name for c in cases]
    assert len(set(names)) == len(names), "duplicated case names"
    return cases


if __name__ == "__main__":
    built = build(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("fuzz-cases"))
    print(f"{len(built)} cases")
