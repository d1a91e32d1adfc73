"""What unexplained matter does to plans from images (issue 31 item 2), judged on the true shelf.

For each held-out look and judge shelf asked for, the frame is perceived by `shelfpick perceive` (as
benchmarks/camera_to_plan.py does: same frames, same matching of perceived to true boxes), and each
of the judge's tasks on it is planned with the physics planner twice on the same perceived scene:
with its `unexplained` regions, and with them taken out (the scene as it was before issue 31's
item 2). Both plans are judged on the true shelf. The figures: plans declared safe, declared safe
that collapsed, ok, and how many plans touch unexplained matter.

    .venv/bin/python -m benchmarks.unexplained_plans --shelves s00,s01,s02,u00,u01,u02 --out /tmp/up.jsonl
"""
from __future__ import annotations

import argparse
import json
import tempfile
from pathlib import Path

from benchmarks.camera_to_plan import HELD_OUT, ROOT, plan_from_image, seen_shelf
from benchmarks.judge_rows import cli_plan_settings, init_worker


def run(a: argparse.Namespace) -> list[dict]:
    judge_dir = str(Path(a.judge_dir).resolve())
    init_worker(judge_dir)
    tasks = json.loads((Path(judge_dir) / "tasks.json").read_text(encoding="utf-8"))
    settings = cli_plan_settings({"workers": 1})
    frames = a.frames or tempfile.mkdtemp(prefix="shelfpick-up-")
    rows = []
    out = open(a.out, "a", encoding="utf-8") if a.out else None
    for look in a.looks.split(","):
        for scene in a.shelves.split(","):
            shelf = seen_shelf(look, scene, judge_dir, frames, None)
            truth = json.loads((Path(judge_dir) / "scenes" / f"{scene}.json").read_text(encoding="utf-8"))
            doc = shelf["scene_doc"]
            regions = len((doc or {}).get("unexplained") or [])
            bare = dict(shelf, scene_doc={k: v for k, v in doc.items() if k != "unexplained"} if doc else None)
            for t in [t for t in tasks if t["scene"] == scene]:
                row = {"look": look, "scene": scene, "target": t["target"], "regions": regions}
                for name, s in (("with", shelf), ("without", bare)):
                    p = plan_from_image(s, t, "physics", settings, a.engine, truth)
                    v = (p.get("judges") or {}).get(a.engine) or {}
                    row[name] = {"declared_safe": p.get("declared_safe"), "ok": v.get("ok"),
                                 "sequence": p.get("sequence"), "error": p.get("error")}
                rows.append(row)
                print(json.dumps(row), flush=True)
                if out:
                    out.write(json.dumps(row) + "\n")
                    out.flush()
    return rows


def summary(rows: list[dict]) -> dict:
    out = {}
    for name in ("with", "without"):
        rs = [r[name] for r in rows if r[name].get("ok") is not None]
        out[name] = {"judged": len(rs), "ok": sum(bool(r["ok"]) for r in rs),
                     "declared_safe": sum(bool(r["declared_safe"]) for r in rs),
                     "declared_safe_collapsed": sum(bool(r["declared_safe"]) and not r["ok"] for r in rs)}
    out["tasks"] = len(rows)
    out["on_frames_with_regions"] = sum(r["regions"] > 0 for r in rows)
    out["sequence_changed"] = sum(r["with"].get("sequence") != r["without"].get("sequence") for r in rows)
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--looks", default=",".join(HELD_OUT))
    ap.add_argument("--shelves", default="s00,s01,s02,u00,u01,u02")
    ap.add_argument("--engine", choices=("pybullet", "mujoco"), default="pybullet")
    ap.add_argument("--frames", default=None)
    ap.add_argument("--out", default=None, help="rows (JSONL, appended)")
    a = ap.parse_args(argv)
    rows = run(a)
    print(json.dumps(summary(rows), indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
