"""Writes the bad-input corpus: scene, plan, camera and image files that `shelfpick plan`,
`simulate` and `perceive` must each refuse with one line naming the file and the field (exit 2).

    python tests/fuzz_corpus/make_corpus.py            # (re)writes tests/fuzz_corpus/cases/ and cases.json

Deterministic (no random draw). Each case is a folder `cases/<name>/` with the bad file(s)
and an entry in `cases.json`: `argv` (the command line; `{good}` is the folder of good files,
`{case}` the case folder, `{tmp}` a scratch folder), `names` (the file the error must name),
`says` (the field, or for a file-level fault what is wrong). Files git cannot hold or that
would be large (a FIFO, a device, a folder, a 10,000-box scene, JSON nested 100,000 deep) are
made at test time by `make_special(name, tmp)`.
"""
from __future__ import annotations

import json
import os
import shutil
import sys
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
W, H = 64, 48

GOOD_SCENE: dict = {
    "format": "shelfpick.scene/1",
    "shelf": {"width": 1.0, "depth": 0.3, "height": 1.6},
    "boxes": [{"id": "a", "size": [0.2, 0.2, 0.2], "position": [-0.2, 0.12, 0.1]},
              {"id": "b", "size": [0.2, 0.2, 0.2], "position": [0.2, 0.12, 0.1]}],
}
GOOD_PLAN: dict = {"format": "shelfpick.plan/1", "task": "extract", "target": "a", "planner": "heuristic",
                   "sequence": ["a"], "safe": True}
GOOD_CAMERA: dict = {"format": "shelfpick.camera/1", "width": W, "height": H, "fx": 60.0, "fy": 60.0,
                     "cx": 32.0, "cy": 24.0, "depth_scale": 0.001,
                     "pose": {"position": [0.0, -1.04, 0.8], "orientation": [0.7071068, -0.7071068, 0.0, 0.0]}}

PLAN = ["plan", "{case}/scene.json", "--task", "clear", "--samples", "1"]
SIMULATE_SCENE = ["simulate", "{case}/scene.json", "{good}/plan.json"]
SIMULATE_PLAN = ["simulate", "{good}/scene.json", "{case}/plan.json"]
PERCEIVE_CAMERA = ["perceive", "--rgb", "{good}/rgb.png", "--depth", "{good}/depth.png",
                   "--camera", "{case}/camera.json", "--out", "{tmp}/out.json"]
PERCEIVE_RGB = ["perceive", "--rgb", "{case}/rgb.png", "--depth", "{good}/depth.png",
                "--camera", "{good}/camera.json", "--out", "{tmp}/out.json"]
PERCEIVE_DEPTH = ["perceive", "--rgb", "{good}/rgb.png", "--depth", "{case}/depth.png",
                  "--camera", "{good}/camera.json", "--out", "{tmp}/out.json"]
PERCEIVE_NPY = [*PERCEIVE_DEPTH[:4], "{case}/depth.npy", *PERCEIVE_DEPTH[5:]]
PERCEIVE_MASKS = ["perceive", "--rgb", "{case}/rgb.png", "--depth", "{good}/depth.png",
                  "--camera", "{good}/camera.json", "--out", "{tmp}/out.json"]


def _copy(doc: Any) -> Any:
    return json.loads(json.dumps(doc))


def scene(**top: Any) -> dict:
    d = _copy(GOOD_SCENE)
    d.update(top)
    return {k: v for k, v in d.items() if v is not DROP}


def box(**over: Any) -> dict:
    """The good scene with box `a` changed (a key set to DROP is removed)."""
    d = _copy(GOOD_SCENE)
    d["boxes"][0].update(over)
    d["boxes"][0] = {k: v for k, v in d["boxes"][0].items() if v is not DROP}
    return d


def plan(**over: Any) -> dict:
    d = _copy(GOOD_PLAN)
    d.update(over)
    return {k: v for k, v in d.items() if v is not DROP}


def camera(**over: Any) -> dict:
    d = _copy(GOOD_CAMERA)
    for k, v in over.items():
        (d["pose"] if k in ("position", "orientation") else d)[k] = v
    return {k: v for k, v in d.items() if v is not DROP}


DROP = object()
NAN, INF = float("nan"), float("inf")


def dumps(doc: Any) -> bytes:
    return json.dumps(doc).encode()  # NaN / Infinity written as JavaScript does, as a broken tool would


# name -> (argv, file written in the case folder, its bytes, what the error must say)
Case = tuple[list[str], str, bytes, str]


def json_cases() -> dict[str, Case]:
    c: dict[str, Case] = {}

    def sc(name: str, data: bytes | dict | list, says: str, argv: list[str] = PLAN) -> None:
        c[f"scene-{name}"] = (argv, "scene.json", data if isinstance(data, bytes) else dumps(data), says)

    sc("not-json", b"{boxes: [1, 2]", "malformed JSON at line 1")
    sc("empty", b"", "malformed JSON")
    sc("trailing-garbage", dumps(GOOD_SCENE) + b" }", "malformed JSON")
    sc("not-utf8", b'{"format": "\xff\xfe"}', "not UTF-8")
    sc("utf16", json.dumps(GOOD_SCENE).encode("utf-16"), "not UTF-8")
    sc("top-list", [GOOD_SCENE], "scene: expected an object, got list")
    sc("top-string", "scene", "scene: expected an object, got str")
    sc("top-null", b"null", "scene: expected an object, got NoneType")
    sc("missing-format", scene(format=DROP), "format: missing required key")
    sc("wrong-format", scene(format="shelfpick.scene/9"), "format: expected 'shelfpick.scene/1'")
    sc("missing-shelf", scene(shelf=DROP), "shelf: missing required key")
    sc("shelf-list", scene(shelf=[1, 0.3, 1.6]), "shelf")
    sc("shelf-negative", scene(shelf={"width": -1, "depth": 0.3, "height": 1.6}), "shelf.width")
    sc("shelf-string", scene(shelf={"width": "1m", "depth": 0.3, "height": 1.6}), "shelf.width")
    sc("shelf-nan", scene(shelf={"width": NAN, "depth": 0.3, "height": 1.6}), "shelf.width")
    sc("shelf-bool", scene(shelf={"width": True, "depth": 0.3, "height": 1.6}), "shelf.width")
    sc("missing-boxes", scene(boxes=DROP), "boxes: missing required key")
    sc("boxes-object", scene(boxes={"a": 1}), "boxes: expected a list, got dict")
    sc("box-number", scene(boxes=[7]), "boxes[0]: expected an object")
    sc("box-no-id", box(id=DROP), "boxes[0].id: missing required key")
    sc("box-empty-id", box(id=""), "boxes[0].id: expected a non-empty string")
    sc("box-numeric-id", box(id=3), "boxes[0].id: expected a non-empty string, got 3")
    sc("duplicate-id", box(id="b"), "boxes[id=b].id: duplicated box id")
    sc("size-two", box(size=[0.2, 0.2]), "boxes[id=a].size: expected a list of 3 numbers")
    sc("size-zero", box(size=[0.2, 0.0, 0.2]), "boxes[id=a].size[1]: must be > 0")
    sc("size-negative", box(size=[-0.2, 0.2, 0.2]), "boxes[id=a].size[0]: must be > 0")
    sc("size-string", box(size=["0.2", 0.2, 0.2]), "boxes[id=a].size[0]: expected a number, got '0.2'")
    sc("position-missing", box(position=DROP), "boxes[id=a].position: missing required key")
    sc("position-infinity", box(position=[0, 0.12, INF]), "boxes[id=a].position[2]: expected a finite number")
    sc("position-1e999", dumps(box()).replace(b"[-0.2, 0.12, 0.1]", b"[-0.2, 0.12, 1e999]"),
       "boxes[id=a].position[2]: expected a finite number, got 1e999")
    sc("quat-zero", box(orientation=[0, 0, 0, 0]), "boxes[id=a].orientation: quaternion has zero length")
    sc("quat-not-unit", box(orientation=[1, 1, 0, 0]), "boxes[id=a].orientation: quaternion is not unit length")
    sc("quat-three", box(orientation=[1, 0, 0]), "boxes[id=a].orientation: expected a list of 4 numbers")
    sc("mass-negative", box(mass=-1), "boxes[id=a].mass: must be > 0")
    sc("depth-known-string", box(depth_known="yes"), "boxes[id=a].depth_known: expected true or false")
    sc("mask-label-zero", box(mask_label=0), "boxes[id=a].mask_label: expected a positive integer")
    sc("box-outside-width", box(position=[0.9, 0.12, 0.1]), "boxes[id=a].position: box 'a' spans x")
    sc("box-behind-wall", box(position=[-0.2, 0.5, 0.1]), "boxes[id=a].position: box 'a' reaches y")
    sc("box-in-front", box(position=[-0.2, -0.5, 0.1]), "boxes[id=a].position: box 'a' lies entirely in front")
    sc("box-below-floor", box(position=[-0.2, 0.12, -0.3]), "boxes[id=a].position: box 'a' spans z")
    sc("nested-40-in-extra", dumps(GOOD_SCENE)[:-1] + b', "note": ' + b"[" * 40 + b"]" * 40 + b"}",
       "note[0][0]")
    sc("digits-5000-size", dumps(box()).replace(b'"size": [0.2', b'"size": [' + b"9" * 5000, 1),
       "boxes[id=a].size[0]: expected an integer of at most 20 digits, got 999999999999...(5000 digits)")
    sc("digits-5000-extra", dumps(GOOD_SCENE)[:-1] + b', "n": -' + b"1" * 5000 + b"}",
       "n: expected an integer of at most 20 digits")
    sc("nan-in-extra", scene(note=[1, NAN]), "note[1]: expected a finite number, got NaN")
    sc("minus-infinity", box(mass=-INF), "boxes[id=a].mass: expected a finite number, got -Infinity")
    sc("boxes-501", scene(boxes=[{"id": f"b{i}", "size": [0.01, 0.01, 0.01], "position": [0, 0.1, 0.01]}
                                 for i in range(501)]), "boxes: 501 boxes; a scene holds at most 500")
    sc("camera-fx-negative", scene(camera=camera(fx=-60.0)), "camera.fx: must be > 0")
    sc("camera-in-scene-string", scene(camera="cam.json"), "camera: expected an object, got str")
    sc("sim-not-json", b"[", "malformed JSON", SIMULATE_SCENE)
    sc("sim-box-nan", box(position=[NAN, 0.12, 0.1]), "boxes[id=a].position[0]", SIMULATE_SCENE)
    sc("sim-wrong-format", scene(format="shelfpick.plan/1"), "format: expected 'shelfpick.scene/1'",
       SIMULATE_SCENE)

    def pl(name: str, data: bytes | dict | list, says: str) -> None:
        c[f"plan-{name}"] = (SIMULATE_PLAN, "plan.json", data if isinstance(data, bytes) else dumps(data), says)

    pl("not-json", b'{"format": ', "malformed JSON")
    pl("top-list", ["a"], "plan: expected an object, got list")
    pl("wrong-format", plan(format="shelfpick.scene/1"), "format: expected 'shelfpick.plan/1'")
    pl("missing-sequence", plan(sequence=DROP), "sequence: missing required key")
    pl("sequence-string", plan(sequence="a"), "sequence: expected a list of box ids, got 'a'")
    pl("sequence-number", plan(sequence=[1]), "sequence: expected a list of box ids, got [1]")
    pl("sequence-twice", plan(task="clear", target=None, sequence=["a", "a"]), "sequence: a box appears twice")
    pl("sequence-unknown-box", plan(target="zz", sequence=["zz"]), "sequence[0]: unknown box id 'zz'")
    pl("task-bogus", plan(task="juggle"), "task: expected one of")
    pl("extract-no-target", plan(target=None), "target: an extract plan needs a box id")
    pl("safe-string", plan(safe="yes"), "safe: expected true or false")
    pl("predicted-object", plan(predicted={"a": 1}), "predicted: expected a list")
    pl("nested-deep", dumps(GOOD_PLAN)[:-1] + b', "x": ' + b'{"a": ' * 50 + b"1" + b"}" * 50 + b"}", "x.a.a")
    pl("digits-5000-seed", dumps(plan(seed=1)).replace(b'"seed": 1', b'"seed": ' + b"7" * 5000),
       "seed: expected an integer of at most 20 digits")
    pl("nan-timing", plan(timing={"total": NAN}), "timing.total: expected a finite number, got NaN")

    def cam(name: str, data: bytes | dict | list, says: str) -> None:
        c[f"camera-{name}"] = (PERCEIVE_CAMERA, "camera.json", data if isinstance(data, bytes) else dumps(data),
                               says)

    cam("not-json", b"fx=60", "malformed JSON")
    cam("top-list", [GOOD_CAMERA], "camera: expected an object, got list")
    cam("wrong-format", camera(format="shelfpick.scene/1"), "format: expected 'shelfpick.camera/1'")
    cam("missing-fx", camera(fx=DROP), "fx: missing required key")
    cam("fx-negative", camera(fx=-60.0), "fx: must be > 0")
    cam("fx-nan", camera(fx=NAN), "fx: expected a finite number, got NaN")
    cam("width-float", camera(width=64.5), "width: expected a positive integer, got 64.5")
    cam("width-zero", camera(width=0), "width: expected a positive integer, got 0")
    cam("width-digits", dumps(camera()).replace(b'"width": 64', b'"width": ' + b"6" * 5000),
        "width: expected an integer of at most 20 digits")
    cam("depth-scale-zero", camera(depth_scale=0), "depth_scale: must be > 0")
    cam("pose-missing", camera(pose=DROP), "pose: missing required key")
    cam("orientation-not-unit", camera(orientation=[1, 1, 1, 1]), "pose.orientation: quaternion is not unit")
    cam("position-short", camera(position=[0, 1]), "pose.position: expected a list of 3 numbers")
    cam("size-mismatch", camera(width=320, height=240, cx=160.0, cy=120.0), "camera is 320x240 but the RGB image is 64x48")
    cam("nested-deep", dumps(GOOD_CAMERA)[:-1] + b', "k": ' + b"[" * 33 + b"]" * 33 + b"}", "k[0]")
    return c


def image_cases() -> dict[str, Case]:
    import cv2
    import numpy as np

    def png(a: np.ndarray) -> bytes:
        ok, buf = cv2.imencode(".png", a)
        assert ok
        return buf.tobytes()

    def npy(a: np.ndarray) -> bytes:
        import io

        f = io.BytesIO()
        np.save(f, a, allow_pickle=a.dtype == object)
        return f.getvalue()

    good_depth = png(depth_units())
    c: dict[str, Case] = {
        "rgb-text": (PERCEIVE_RGB, "rgb.png", b"this is not an image", "rgb.png: not a readable image"),
        "rgb-empty": (PERCEIVE_RGB, "rgb.png", b"", "rgb.png: empty file (0 bytes)"),
        "rgb-truncated": (PERCEIVE_RGB, "rgb.png", png(rgb_image())[:200], "rgb.png: truncated PNG"),
        "rgb-tiny": (PERCEIVE_RGB, "rgb.png", png(np.zeros((8, 8, 3), np.uint8)), "rgb.png: image is 8x8 px"),
        "depth-truncated": (PERCEIVE_DEPTH, "depth.png", good_depth[:100], "depth.png: truncated PNG"),
        "depth-8bit": (PERCEIVE_DEPTH, "depth.png", png((depth_units() // 16).astype(np.uint8)),
                       "depth.png: depth image must be uint16"),
        "depth-3-channel": (PERCEIVE_DEPTH, "depth.png", png(np.dstack([depth_units()] * 3)),
                            "depth.png: depth image must have one channel"),
        "depth-half-size": (PERCEIVE_DEPTH, "depth.png", png(depth_units()[:24, :32]),
                            "depth.png: depth image is 32x24 but the RGB image is 64x48"),
        "depth-all-zero": (PERCEIVE_DEPTH, "depth.png", png(np.zeros((H, W), np.uint16)),
                           "depth.png: depth image has no valid pixel"),
        "depth-flat": (PERCEIVE_DEPTH, "depth.png", png(np.full((H, W), 1040, np.uint16)),
                       "depth.png: depth is flat"),
        "depth-metres-in-uint16": (PERCEIVE_DEPTH, "depth.png", png((depth_units() // 1000 + 1).astype(np.uint16)),
                                   "depth.png: median depth"),
        "npy-3d": (PERCEIVE_NPY, "depth.npy", npy(np.ones((4, 4, 2), np.float32)),
                   "depth.npy: depth array must be 2-D"),
        "npy-strings": (PERCEIVE_NPY, "depth.npy", npy(np.full((4, 4), "x")), "depth.npy: depth array must be numbers"),
        "npy-pickle": (PERCEIVE_NPY, "depth.npy", npy(np.array([{"a": 1}], dtype=object)),
                       "depth.npy: not a readable .npy depth array"),
        "npy-negative": (PERCEIVE_NPY, "depth.npy", npy(np.full((4, 4), -1.0, np.float32)),
                         "depth.npy: 16 negative depth values"),
        "npy-garbage": (PERCEIVE_NPY, "depth.npy", b"\x93NUMPY garbage", "depth.npy: not a readable .npy"),
    }
    return c


def mask_cases() -> dict[str, tuple[list[str], dict[str, bytes], str]]:
    import cv2
    import numpy as np

    rgb = cv2.imencode(".png", rgb_image())[1].tobytes()
    masks = cv2.imencode(".png", np.zeros((H, W), np.uint16))[1].tobytes()

    def with_json(doc: Any) -> dict[str, bytes]:
        return {"rgb.png": rgb, "masks.png": masks, "masks.json": dumps(doc)}

    return {
        "masks-key-not-integer": (PERCEIVE_MASKS, with_json({"x": "a"}), "masks.json: 'x': expected a mask label"),
        "masks-key-float": (PERCEIVE_MASKS, with_json({"1.5": "a"}), "masks.json: '1.5': expected a mask label"),
        "masks-value-number": (PERCEIVE_MASKS, with_json({"1": 2}), "masks.json: 1: expected a box id"),
        "masks-list": (PERCEIVE_MASKS, with_json(["a"]), "masks.json: expected an object of mask label"),
        "masks-nan": (PERCEIVE_MASKS, {"rgb.png": rgb, "masks.png": masks, "masks.json": b'{"1": NaN}'},
                      "masks.json: 1: expected a finite number, got NaN"),
        "masks-png-rgb": (PERCEIVE_MASKS, {"rgb.png": rgb, "masks.png": rgb, "masks.json": dumps({"1": "a"})},
                          "masks.png: mask image must be one channel of 64x48 px"),
    }


# files made at test time: name -> (argv, names, says)
SPECIAL: dict[str, tuple[list[str], str, str]] = {
    "scene-fifo": (["plan", "{tmp}/fifo.json", "--task", "clear"], "{tmp}/fifo.json", "a FIFO, not a regular file"),
    "scene-device": (["plan", "/dev/zero", "--task", "clear"], "/dev/zero", "a device, not a regular file"),
    "scene-folder": (["plan", "{tmp}/folder.json", "--task", "clear"], "{tmp}/folder.json",
                     "a folder, not a regular file"),
    "scene-missing": (["plan", "{tmp}/nope.json", "--task", "clear"], "{tmp}/nope.json", "file not found"),
    "scene-10000-boxes": (["plan", "{tmp}/big.json", "--task", "clear"], "{tmp}/big.json",
                          "boxes: 10000 boxes; a scene holds at most 500"),
    "scene-nested-100k": (["plan", "{tmp}/deep.json", "--task", "clear"], "{tmp}/deep.json",
                          "document: nested deeper than 32 levels"),
    "plan-fifo": (["simulate", "{good}/scene.json", "{tmp}/fifo.json"], "{tmp}/fifo.json",
                  "a FIFO, not a regular file"),
    "plan-device": (["simulate", "{good}/scene.json", "/dev/null"], "/dev/null", "a device, not a regular file"),
    "camera-fifo": ([*PERCEIVE_CAMERA[:5], "--camera", "{tmp}/fifo.json", "--out", "{tmp}/out.json"],
                    "{tmp}/fifo.json", "a FIFO, not a regular file"),
    "camera-device": ([*PERCEIVE_CAMERA[:5], "--camera", "/dev/zero", "--out", "{tmp}/out.json"], "/dev/zero",
                      "a device, not a regular file"),
}


def make_special(name: str, tmp: Path) -> None:
    """Create what a SPECIAL case needs in `tmp` (a FIFO, a folder, a large file)."""
    tmp.mkdir(parents=True, exist_ok=True)
    if name.endswith("-fifo") and not (tmp / "fifo.json").exists():
        os.mkfifo(tmp / "fifo.json")
    elif name == "scene-folder":
        (tmp / "folder.json").mkdir(exist_ok=True)
    elif name == "scene-10000-boxes":
        d = _copy(GOOD_SCENE)
        d["boxes"] = [{"id": f"b{i}", "size": [0.01, 0.01, 0.01], "position": [0, 0.1, 0.01]} for i in range(10000)]
        (tmp / "big.json").write_bytes(dumps(d))
    elif name == "scene-nested-100k":
        (tmp / "deep.json").write_bytes(b"[" * 100_000 + b"]" * 100_000)


def depth_units():
    """A small shelf front in depth: the back at 1.34 m, one box face at 1.06 m (uint16 mm)."""
    import numpy as np

    d = np.full((H, W), 1340, np.uint16)
    d[20:44, 10:34] = 1060
    return d


def rgb_image():
    import numpy as np

    img = np.full((H, W, 3), 90, np.uint8)
    img[20:44, 10:34] = (160, 120, 80)
    return img


def write_good(d: Path) -> None:
    import cv2

    d.mkdir(parents=True, exist_ok=True)
    (d / "scene.json").write_bytes(dumps(GOOD_SCENE))
    (d / "plan.json").write_bytes(dumps(GOOD_PLAN))
    (d / "camera.json").write_bytes(dumps(GOOD_CAMERA))
    cv2.imwrite(str(d / "rgb.png"), rgb_image())
    cv2.imwrite(str(d / "depth.png"), depth_units())


def cases() -> dict[str, dict]:
    """name -> {argv, files: {name: bytes}, names, says} for the files written in the corpus."""
    out: dict[str, dict] = {}
    for name, (argv, fname, data, says) in {**json_cases(), **image_cases()}.items():
        out[name] = {"argv": argv, "files": {fname: data}, "names": f"{{case}}/{fname}", "says": says}
    for name, (argv, files, says) in mask_cases().items():
        bad = "masks.png" if name == "masks-png-rgb" else "masks.json"
        out[name] = {"argv": argv, "files": files, "names": f"{{case}}/{bad}", "says": says}
    return out


def write(root: Path = HERE) -> dict:
    """(Re)write `root/good/`, `root/cases/<name>/` and `root/cases.json`; returns the manifest."""
    write_good(root / "good")
    shutil.rmtree(root / "cases", ignore_errors=True)
    manifest: dict[str, dict] = {}
    for name, case in sorted(cases().items()):
        d = root / "cases" / name
        d.mkdir(parents=True)
        for fname, data in case["files"].items():
            (d / fname).write_bytes(data)
        manifest[name] = {"argv": case["argv"], "names": case["names"], "says": case["says"]}
    for name, (argv, names, says) in sorted(SPECIAL.items()):
        manifest[name] = {"argv": argv, "names": names, "says": says, "special": True}
    (root / "cases.json").write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    return manifest


if __name__ == "__main__":
    m = write(Path(sys.argv[1]) if len(sys.argv) > 1 else HERE)
    print(f"{len(m)} cases")
