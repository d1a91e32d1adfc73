"""The gate on the demo shelves (issue 32): the README's example plan, and every box lifted off the
top of others, planned from the scene file and from its front faces alone (depths hidden).

    .venv/bin/python benchmarks/risk_demo.py [--workers 1] [--md OUT.md]

A box "on top of others" has nothing resting on it (free space above it) and stands on another box.
For each such box: the plan `shelfpick plan` makes (default settings), whether it is the box alone,
and the gate's verdict (calibrated chance, its upper end, the worlds asked).
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

DEMO = ROOT / "static" / "demo"
README_EXAMPLE = ("demo-structured-10.json", "b1")


def tops(scene) -> list[str]:
    """Boxes with free space above them that stand on another box (not on the shelf floor)."""
    from shelfpick.planning.sim import ShelfSim

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sim = ShelfSim(scene)
    try:
        return [b.id for b in scene.boxes if sim.free_lift(b.id) > 0.003 and b.position[2] - b.size[2] / 2 > 0.05]
    finally:
        sim.close()


def row(name: str, scene, target: str, how: str, workers: int) -> dict:
    from shelfpick.planning.planner import make_plan

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        plan = make_plan(scene, "extract", target, workers=workers)
    g = plan.extra["search"].get("plan_risk", {})
    return {"shelf": name, "target": target, "scene": how, "sequence": " ".join(plan.sequence), "safe": plan.safe,
            "probability": g.get("probability"), "high": g.get("high"), "failed": g.get("failed_worlds"),
            "worlds": g.get("worlds")}


def main(argv: list[str] | None = None) -> int:
    from shelfpick.perception.scene import Scene

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--md")
    a = ap.parse_args(argv)
    rows = []
    for path in sorted(DEMO.glob("*.json")):
        scene = Scene.load(path)
        targets = tops(scene)
        if path.name == README_EXAMPLE[0] and README_EXAMPLE[1] not in targets:
            targets = [README_EXAMPLE[1]] + targets
        for t in targets:
            for how, sc in (("file", scene), ("faces only", scene.hide_depths())):
                r = row(path.name, sc, t, how, a.workers)
                rows.append(r)
                print(r, flush=True)
    out = ["| shelf | target | planned from | plan | safe | calibrated chance | upper end | failed worlds |",
           "|---|---|---|---|---|---:|---:|---:|"]
    for r in rows:
        out.append(f"| {r['shelf']} | {r['target']} | {r['scene']} | {r['sequence']} | {'yes' if r['safe'] else 'no'} | "
                   f"{r['probability']:.3f} | {r['high']:.3f} | {r['failed']}/{r['worlds']} |")
    safe = sum(r["safe"] for r in rows)
    out.append("")
    out.append(f"{safe} of {len(rows)} plans declared safe.")
    text = "\n".join(out) + "\n"
    print(text)
    if a.md:
        Path(a.md).write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
