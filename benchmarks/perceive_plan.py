"""Does perception cost safety? Plans from the perceived scene vs from the true scene.

For each synthetic shelf (planning.shelves.generate, settled, structured and
unstructured): render it (perception.render, noise on), perceive it
(perception.pipeline.perceive), pick a seeded target box, then
- plan A from the true scene with its depths hidden (what a perfect perception gives),
- plan B from the perceived scene (its own box ids, depth unknown),
and execute both on the TRUE scene (planning.execute.execute_plan). Perceived ids
are mapped to true boxes by pixel overlap of the perceived mask with the true
front faces (the robot's suction cup lands on whatever box is there); a plan
whose target was not perceived, or that cannot be made at all (perceived boxes that
cannot stand as perceived), counts as not safe. Reported: both safe rates,
target-perceived rate, mean plan length, plan time.

    .venv/bin/python benchmarks/perceive_plan.py --count 6 --seed 0 --out perceive-plan
"""
from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def map_ids(perc_masks: np.ndarray, perc_scene, gt: dict[str, np.ndarray]) -> dict[str, str]:
    """Perceived box id -> true box id whose visible front face holds most of its mask."""
    out = {}
    for b in perc_scene.boxes:
        m = perc_masks == b.mask_label
        n = int(m.sum())
        if n == 0:
            continue
        best, best_n = None, 0
        for tid, g in gt.items():
            k = int(np.logical_and(m, g).sum())
            if k > best_n:
                best, best_n = tid, k
        if best is not None and best_n >= 0.3 * n:
            out[b.id] = best
    return out


def run_one(kind: str, seed: int, n_boxes: int, samples: int, task: str, segmenter) -> dict:
    from perception.bench_truth import front_face_masks
    from perception.errors import ShelfpickError
    from perception.pipeline import perceive
    from perception.render import render
    from planning.execute import execute_plan
    from planning.planner import make_plan
    from planning.shelves import generate

    truth = generate(kind, seed, n_boxes)
    cap = render(truth, seed=seed)
    gt = front_face_masks(truth, cap)
    res = perceive(cap, segmenter, truth.shelf)
    ids = map_ids(res.masks, res.scene, gt)
    rng = np.random.default_rng(seed)
    visible = sorted(gt)
    target = visible[int(rng.integers(len(visible)))] if task == "extract" else None
    row: dict = {"kind": kind, "seed": seed, "boxes": len(truth.boxes), "perceived": len(res.scene.boxes),
                 "target": target}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        plan_t = make_plan(truth.hide_depths(), task, target, samples=samples, seed=seed)
        row["truth_plan_s"] = time.perf_counter() - t
        ex_t = execute_plan(truth, plan_t.sequence, seed=seed)
        row["truth_sequence"] = list(plan_t.sequence)
        row["truth_safe"] = bool(ex_t.ok)
        ptarget = None
        if target is not None:
            cands = [pid for pid, tid in ids.items() if tid == target]
            if cands:   # the perceived box that covers most of the target
                ptarget = max(cands, key=lambda p: int(((res.masks == res.scene.require(p).mask_label)
                                                        & gt[target]).sum()))
        row["target_perceived"] = ptarget is not None or task != "extract"
        if task == "extract" and ptarget is None:
            row["perceived_safe"] = False
            row["perceived_sequence"] = []
            row["note"] = "target not perceived"
            return row
        t = time.perf_counter()
        try:
            plan_p = make_plan(res.scene, task, ptarget, samples=samples, seed=seed)
        except ShelfpickError as e:   # e.g. the perceived boxes cannot stand as perceived
            row["perceived_safe"] = False
            row["perceived_sequence"] = []
            row["note"] = f"no plan from the perceived scene: {e}"
            return row
        row["perceived_plan_s"] = time.perf_counter() - t
        seq, seen = [], set()
        for pid in plan_p.sequence:
            tid = ids.get(pid)
            if tid is None or tid in seen:
                continue   # a fragment of a box already pulled, or no box there
            seen.add(tid)
            seq.append(tid)
        if task == "extract" and target not in seq:
            seq.append(target)
        if task == "clear":   # boxes perception missed are pulled last, as an operator would
            seq += [b.id for b in truth.boxes if b.id not in seen]
        ex_p = execute_plan(truth, seq, seed=seed)
        row["perceived_sequence"] = seq
        row["perceived_safe"] = bool(ex_p.ok)
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--count", type=int, default=6, help="scenes (half structured, half unstructured)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--boxes", type=int, default=10)
    ap.add_argument("--samples", type=int, default=10, help="depth samples of the physics planner")
    ap.add_argument("--task", choices=("extract", "clear"), default="extract")
    ap.add_argument("--segmenter", choices=("auto", "depth", "yolo"), default="auto")
    ap.add_argument("--weights")
    ap.add_argument("--out", default="perceive-plan")
    args = ap.parse_args(argv)
    from tqdm import tqdm

    from perception.segment import load_segmenter, segmenter_name

    seg = load_segmenter(args.weights, args.segmenter)
    rows = []
    for i in tqdm(range(args.count), desc="scenes"):
        kind = "structured" if i % 2 == 0 else "unstructured"
        rows.append(run_one(kind, args.seed + i, args.boxes, args.samples, args.task, seg))
    n = len(rows)
    summary = {"segmenter": segmenter_name(seg), "task": args.task, "scenes": n,
               "truth_safe_rate": sum(r["truth_safe"] for r in rows) / n,
               "perceived_safe_rate": sum(r["perceived_safe"] for r in rows) / n,
               "target_perceived_rate": sum(r["target_perceived"] for r in rows) / n,
               "mean_truth_plan_len": float(np.mean([len(r["truth_sequence"]) for r in rows])),
               "mean_perceived_plan_len": float(np.mean([len(r["perceived_sequence"]) for r in rows])),
               "rows": rows}
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "perceive_plan.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    print(f"segmenter {summary['segmenter']}, task {args.task}, {n} scenes: "
          f"safe from true scene {summary['truth_safe_rate']:.2f}, "
          f"safe from perceived scene {summary['perceived_safe_rate']:.2f}, "
          f"target perceived {summary['target_perceived_rate']:.2f}")
    for r in rows:
        print(f"  {r['kind']}-{r['seed']}: boxes {r['boxes']} perceived {r['perceived']} target {r['target']} "
              f"truth {'safe' if r['truth_safe'] else 'UNSAFE'} {r['truth_sequence']} | perceived "
              f"{'safe' if r['perceived_safe'] else 'UNSAFE'} {r['perceived_sequence']} {r.get('note', '')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
