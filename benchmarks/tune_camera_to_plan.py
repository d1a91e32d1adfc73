"""From the camera to a plan that holds, on the TUNING role (issue 31): what camera_to_plan.py measures on
the held-out looks, measured where one may look frame by frame and choose things.

camera_to_plan.py renders the judge's shelves with the held-out looks; its figures may not be used to
choose anything (docs/perception.md, "Roles"). This runs the same chain on the tuning shelves
(`planning.shelves.generate`, seeds 31000-31059, even structured, odd unstructured: the shelves
perceive_generated.py uses) and a tuning look (`flat` or `labels`):

1. the shelf is rendered by the look (frame seed 0) and perceived in this process (`perceive`, default
   segmenter); perceived boxes are matched to true ones by front-face position (`match_fronts`);
2. targets: `--targets` true boxes a shelf whose front the camera sees (>= VISIBLE_PX pixels), drawn
   with a seeded generator (`[seed, 7]`); each is planned from the perceived scene with `shelfpick plan`'s
   defaults by the physics planner (B) and highest-first (H), translated to true ids and judged on the
   TRUE shelf by the judge's engine (../shared/judge, imported at run time, never copied);
3. the same task planned on the true faces with 1 cm of error (the judge's `observe.py --noise 0.01`,
   physics planner) and judged the same way (T): the tasks where T holds are the ones "some plan holds".

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/tune_camera_to_plan.py --look labels --seeds 31000-31019 --out /tmp/tc2p/labels.jsonl

Rows (one JSON line a shelf, flushed; `--resume` keeps rows made with the same settings) go to `--out`,
the summary to `<out>.md` (also printed).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.camera_to_plan import VISIBLE_PX, match_fronts, plan_from_image, visible_fronts  # noqa: E402
from benchmarks.judge_rows import (UsageError, cli_plan_settings, init_worker, judged, kept_rows,  # noqa: E402
                                   make_timed_plan, print_report)
from benchmarks.judge_summary import engine_summary  # noqa: E402
from benchmarks.perceive_generated import TUNE_LOOKS, tune_scene, tuning_look, tuning_seeds  # noqa: E402

TRUE_NOISE = 0.01


def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--look", default="labels", help=f"a tuning look: {', '.join(TUNE_LOOKS)}")
    ap.add_argument("--seeds", default="31000-31019", help="tuning shelves: a range A-B or a comma list")
    ap.add_argument("--targets", type=int, default=3, help="targets a shelf (seeded)")
    ap.add_argument("--engine", choices=("pybullet", "mujoco"), default="pybullet")
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--out", required=True, help="rows (JSONL); frames go to <out>.frames, the summary to <out>.md")
    ap.add_argument("--resume", action="store_true", help="keep rows already in --out made with the same settings")
    return ap.parse_args(argv)


def targets_of(truth: dict, seen: set[str], seed: int, n: int) -> list[str]:
    """`n` true boxes whose front the camera sees, drawn with the shelf's own seeded generator."""
    import numpy as np

    ids = sorted(b["id"] for b in truth["boxes"] if b["id"] in seen)
    rng = np.random.default_rng([seed, 7])
    return [ids[int(i)] for i in sorted(rng.choice(len(ids), min(n, len(ids)), replace=False))]


def seen_shelf(truth: dict, look: str, seed: int, frames: Path) -> dict:
    """Render, perceive in process, match: the shelf as camera_to_plan's plan_from_image wants it."""
    from benchmarks.generators import write_frame
    from shelfpick.perception.capture import load_capture
    from shelfpick.perception.errors import ShelfpickError
    from shelfpick.perception.pipeline import perceive

    folder = frames / look / str(seed)
    paths = write_frame(truth, look, 0, folder, f"tune{seed}")
    visible = visible_fronts(truth, folder)
    counted = {k for k, n in visible.items() if n >= VISIBLE_PX}
    out: dict[str, Any] = {"true_fronts": len(counted), "counted": sorted(counted), "error": ""}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = perceive(load_capture(paths["rgb"], paths["depth"], paths["camera"]))
    except ShelfpickError as exc:
        return dict(out, error=str(exc)[:300], perceived=0, matched=0, matched_true=0, ids={}, scene_doc=None)
    doc = res.scene.to_json()
    m = match_fronts(doc, truth)
    return dict(out, perceived=len(doc["boxes"]), matched=len(m), matched_true=sum(1 for t, _ in m.values() if t in counted),
                ids={p: t for p, (t, _) in m.items()}, scene_doc=doc)


def true_faces_plan(truth: dict, target: str, seed: int, settings: dict, engine: str) -> dict:
    """T: the task planned on the true faces with 1 cm of error (the judge's observe), judged on the truth."""
    from observe import observed

    fields, doc = make_timed_plan(observed(truth, noise=TRUE_NOISE, seed=seed + 17), target, "physics", settings)
    return dict(fields, judges={engine: judged(engine, truth, dict(doc, target=target))} if doc else {})


def run_shelf(seed: int, a: argparse.Namespace, settings: dict, sid: str, frames: Path) -> dict:
    """One shelf: its segmentation figures and each target's B, H and T plans."""
    init_worker(a.judge_dir)
    truth = tune_scene(seed, frames / "shelves")
    shelf = seen_shelf(truth, a.look, seed, frames)
    kind = "structured" if seed % 2 == 0 else "unstructured"
    row = {"key": f"{a.look}|{seed}", "settings": sid, "seed": seed,
           "shelf": {k: v for k, v in shelf.items() if k != "scene_doc"}, "tasks": []}
    for target in targets_of(truth, set(shelf["counted"]), seed, a.targets):
        task = {"target": target, "kind": kind, "exhaustive": False, "min_removals": None}
        row["tasks"].append({"target": target,
                             **{p: plan_from_image(shelf, task, planner, settings, a.engine, truth)
                                for p, planner in (("physics", "physics"), ("highest_first", "heuristic"))},
                             "true": dict(true_faces_plan(truth, target, seed, settings, a.engine), **task)})
    return row


def summarize(rows: Sequence[dict], engine: str) -> dict:
    """Segmentation over the shelves; B, H and T over the tasks, and B and H where T holds."""
    held = lambda p: bool(p.get("judges", {}).get(engine, {}).get("ok"))  # noqa: E731
    shelves = [r["shelf"] for r in rows]
    fronts, perceived = sum(s["true_fronts"] for s in shelves), sum(s["perceived"] for s in shelves)
    tasks = [t for r in rows for t in r["tasks"]]
    can = [t for t in tasks if held(t["true"])]
    return {"shelves": len(rows), "true_fronts": fronts, "perceived": perceived,
            "recall": sum(s["matched_true"] for s in shelves) / fronts if fronts else float("nan"),
            "precision": sum(s["matched"] for s in shelves) / perceived if perceived else float("nan"),
            "plans": {p: engine_summary([t[p] for t in tasks], engine) for p in ("physics", "highest_first", "true")},
            "where_true_holds": {p: [sum(1 for t in can if held(t[p])), len(can)] for p in ("physics", "highest_first")},
            "not_perceived": sum(1 for t in tasks if t["physics"].get("error") == "target not perceived")}


def to_markdown(s: dict, header: str) -> str:
    """A segmentation line and the plans table."""
    pct = lambda a, b: f"{100 * a / b:.0f}%" if b else "-"  # noqa: E731
    lines = ["# From the camera to a plan that holds (tuning role)\n", header + "\n",
             f"- segmentation on {s['shelves']} shelves: recall {s['recall']:.3f} ({s['true_fronts']} true fronts "
             f">= {VISIBLE_PX} px), precision {s['precision']:.3f} ({s['perceived']} perceived)",
             f"- targets never perceived: {s['not_perceived']}", "",
             "| plan | ok | where the true faces' plan holds | declared safe that collapsed | plan errors |",
             "|---|---|---|---|---|"]
    w = s["where_true_holds"]
    for name, key in (("from the image, physics", "physics"), ("from the image, highest-first", "highest_first"),
                      ("true faces + 1 cm, physics", "true")):
        p = s["plans"][key]
        where = f"{w[key][0]}/{w[key][1]} ({pct(*w[key])})" if key in w else "-"
        lines.append(f"| {name} | {p['ok']}/{p['tasks']} ({pct(p['ok'], p['tasks'])}) | {where} | "
                     f"{p['declared_safe_collapsed']}/{p['declared_safe']} | {p['plan_errors']} |")
    return "\n".join(lines) + "\n"


def run(a: argparse.Namespace) -> dict:
    """Keep the rows `--resume` allows, run the other shelves here, summarize them all."""
    try:
        tuning_look(a.look)
        seeds = tuning_seeds(a.seeds)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    a.judge_dir = str(Path(a.judge_dir).resolve())
    settings = cli_plan_settings({})
    sid = json.dumps({"plan": settings, "engine": a.engine, "targets": a.targets, "look": a.look,
                      "visible_px": VISIBLE_PX}, sort_keys=True)
    out = Path(a.out)
    frames = out.with_suffix(".frames")
    rows = kept_rows(out, a.resume, sid, {f"{a.look}|{s}" for s in seeds})
    done = {r["seed"] for r in rows}
    t0 = time.perf_counter()
    with out.open("w", encoding="utf-8") as f:
        for r in rows:
            f.write(json.dumps(r) + "\n")
        for i, seed in enumerate(s for s in seeds if s not in done):
            row = run_shelf(seed, a, settings, sid, frames)
            f.write(json.dumps(row) + "\n")
            f.flush()
            rows.append(row)
            print(f"[{i + 1}/{len(seeds) - len(done)}] {seed} {time.perf_counter() - t0:.0f}s "
                  + " ".join(f"{t['target']}:B={'ok' if t['physics'].get('judges', {}).get(a.engine, {}).get('ok') else 'x'}"
                             for t in row["tasks"]), file=sys.stderr, flush=True)
    summary = summarize(rows, a.engine)
    summary["run"] = {"wall_s": round(time.perf_counter() - t0, 1), "seeds": seeds, "look": a.look}
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Run, print and write the summary (<out>.md); 2 on a bad argument."""
    a = parse_args(argv)

    def header(summary: dict) -> str:
        r = summary["run"]
        return (f"tune_camera_to_plan: look `{r['look']}`, tuning shelves {r['seeds'][0]}-{r['seeds'][-1]} "
                f"({len(r['seeds'])}), {a.targets} targets a shelf, {a.engine} judge on the true shelf; {r['wall_s']} s")
    return 0 if print_report("tune_camera_to_plan", run, a, header, to_markdown, Path(a.out).with_suffix(".md")) is not None else 2


if __name__ == "__main__":
    sys.exit(main())
