"""The neura pallet (a real RGB-D frame looking down at cartons) through `shelfpick perceive` and a
camera file, no special code path: recall and precision against its instance masks.

A pallet seen from above is a shelf on its back (docs/cameras.md): shelf +y points down into the
pallet, shelf +z along the world's y, the shelf's front plane just above the top layer and its
back wall just above the floor. Two camera files are written from the capture's intrinsics and
`cam2root` (4x4 camera to world, z up), differing only in the shelf frame's rotation:
- `level`: the shelf's y axis is the world's -z (the robot's calibration taken as exact);
- `floor`: the shelf's y axis is the floor's normal measured in the depth (`bench.fit_floor`),
  what `shelfpick calibrate --plane floor` gives with a board lying on the floor: this capture's
  cam2root is ~10 deg off the floor, and a back wall that is not parallel to the floor leaves
  the floor, seen at a slant, in front of it.
The shelf's extents come from the points (1st/99th percentiles, 5 cm over the top layer, 3 cm
over the floor), as a user would measure the cell once.

    .venv/bin/python benchmarks/perceive_neura.py --out /tmp/neura [--segmenter learned]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))


def camera_files(neura: Path, out: Path) -> dict[str, tuple[Path, tuple[float, float, float]]]:
    """Write `level` and `floor` camera files; name -> (path, shelf width, depth, height)."""
    from dataclasses import replace

    from shelfpick.perception.evaluation.bench import WORLD_TO_SHELF_DOWN, _rotation_onto, fit_floor
    from shelfpick.perception.capture import read_depth
    from shelfpick.perception.geometry import camera_from_matrix, matrix_to_quat, point_map
    from shelfpick.perception.scene import quat_to_matrix

    d = neura / "data" / "small_box"
    intr = json.loads((d / "intrinsics.json").read_text())
    cam2root = np.asarray(json.loads((d / "cam2root.json").read_text())["cam2root"])
    depth = read_depth(d / "raw_depth.png", 0.001)
    valid = depth > 0
    files = {}
    for name in ("level", "floor"):
        cam = camera_from_matrix(intr, cam2root, WORLD_TO_SHELF_DOWN)
        normal, on_floor = fit_floor(point_map(cam, depth)[valid])
        if name == "floor":
            turn = _rotation_onto(normal, np.array([0.0, 1.0, 0.0]))
            cam = replace(cam, position=tuple(float(v) for v in turn @ np.asarray(cam.position)),
                          orientation=matrix_to_quat(turn @ np.asarray(quat_to_matrix(cam.orientation))))
            floor_y = float((turn @ on_floor)[1])
        else:
            floor_y = float(np.percentile(point_map(cam, depth)[valid][:, 1], 99))
        pts = point_map(cam, depth)[valid]
        top = float(np.percentile(pts[:, 1], 1))
        xlo, xhi = np.percentile(pts[:, 0], [1, 99])
        zlo, zhi = np.percentile(pts[:, 2], [1, 99])
        shift = np.array([-(xlo + xhi) / 2, -(top - 0.05), -zlo])
        cam = replace(cam, position=tuple(float(p + s) for p, s in zip(cam.position, shift)))
        shelf = (float(xhi - xlo), float(floor_y - 0.03 - (top - 0.05)), float(zhi - zlo))
        out.mkdir(parents=True, exist_ok=True)
        cam.save(out / f"camera_{name}.json")
        files[name] = (out / f"camera_{name}.json", shelf)
    return files


def perceive_through_cli(neura: Path, cam_file: Path, shelf, out: Path, tag: str,
                         segmenter: str = "auto") -> dict:
    import cv2

    from shelfpick.console.cli import main
    from shelfpick.perception.evaluation.bench import match

    d = neura / "data" / "small_box"
    masks = out / f"masks_{tag}.png"
    rc = main(["perceive", "--rgb", str(d / "color_image.png"), "--depth", str(d / "raw_depth.png"),
               "--camera", str(cam_file), "--out", str(out / f"scene_{tag}.json"), "--masks", str(masks),
               "--overlay", str(out / f"overlay_{tag}.png"), "--no-catalogue", "--segmenter", segmenter,
               "--shelf", *(f"{v:.4f}" for v in shelf)])
    if rc != 0:
        return {"rc": rc}
    labels = cv2.imread(str(neura / "derived" / "instance_labels_small_box_scene.png"), cv2.IMREAD_UNCHANGED)
    meta = json.loads((neura / "derived" / "instances_small_box_scene.json").read_text())
    truth = [labels == int(i["label"]) for i in meta["instances"] if (labels == int(i["label"])).sum() >= 200]
    lab = cv2.imread(str(masks), cv2.IMREAD_UNCHANGED)
    preds = [lab == k for k in np.unique(lab) if k]
    pairs = match(preds, truth)
    return {"boxes": len(truth), "predicted": len(preds), "matched": len(pairs),
            "recall": len(pairs) / len(truth), "precision": len(pairs) / max(1, len(preds)),
            "shelf": [round(v, 4) for v in shelf], "camera": json.loads(cam_file.read_text())}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--realdata", default=str(ROOT.parent / "shared" / "realdata"))
    ap.add_argument("--out", default="perceive-neura")
    ap.add_argument("--segmenter", default="auto", help="as `perceive --segmenter` (auto, depth, learned, ...)")
    args = ap.parse_args(argv)
    neura = Path(args.realdata) / "neura_smart_palletizer"
    if not neura.is_dir():
        print(f"{neura}: not found", file=sys.stderr)
        return 2
    out = Path(args.out)
    res = {name: perceive_through_cli(neura, f, shelf, out, name, args.segmenter)
           for name, (f, shelf) in camera_files(neura, out).items()}
    (out / "report.json").write_text(json.dumps(res, indent=1))
    for name, r in res.items():
        print(f"{name}: recall {r.get('recall', 0):.3f} ({r.get('matched')}/{r.get('boxes')}), precision "
              f"{r.get('precision', 0):.3f} ({r.get('predicted')} masks), shelf {r.get('shelf')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
