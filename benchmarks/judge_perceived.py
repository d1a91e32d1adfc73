"""Plans from perceived renders of the judge's true shelves vs plans from the judge's own observation (#14).

Issue 14 asks that plans made from a perceived scene hold on the true shelf as often as plans made
from the true scene. For each task of the independent judge (../shared/judge, imported at run time,
never copied), on its TRUE shelf:

- A: the judge's own observation at noise 0 (front faces exact, depth unknown), planned by `make_plan`
  exactly as judge_report's units plan it (`judge_rows.run_unit`);
- B: the shelf rendered by our renderer through a framing camera (`perceive_plan.framing_camera`:
  every front face in view), perceived with the default segmenter (`auto`), planned on the perceived
  scene for the perceived box that covers the target; perceived ids are mapped to true ids by pixel
  overlap (`perceive_plan.map_ids`). A target not perceived is a failed task (counted on its own); a plan
  step on a perceived box that maps to no true box fails the plan (the judge still runs the rest).

Both plans use `shelfpick plan`'s defaults (`judge_rows.cli_plan_settings`) and are judged on the true
shelf by the judge's PyBullet engine, its MuJoCo engine, or both (`--engine both`).

    .venv/bin/python benchmarks/judge_perceived.py --engine both --jobs 1 --out /tmp/jp/all.jsonl
    .venv/bin/python benchmarks/judge_perceived.py --tasks s00:b5 --out /tmp/jp/one.jsonl [--resume]

Writes `--out` rows (one JSON line per task, flushed as each finishes; `--resume` keeps the rows made
with the same settings) and `<out>.md` (the summary, also printed).
"""
from __future__ import annotations

import argparse
import functools
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import (TASK_FILTERS, UsageError, cli_plan_settings,  # noqa: E402
                                   collect_rows, judged, kept_rows, load_tasks, make_timed_plan,
                                   observe_seed, print_report, run_unit)
from benchmarks.judge_summary import ENGINES, engine_summary, percentile  # noqa: E402

SEGMENTER = "auto"
UNMAPPED = "unmapped:"          # a plan step on a perceived box that is no true box (the judge skips it)
HEADER = ("scene", "target", "kind", "n_boxes", "noise", "planner", "exhaustive", "min_removals", "settings")


# --------------------------------------------------------------------------
# arguments and units
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"),
                    help="the independent judge's folder (default ../shared/judge)")
    ap.add_argument("--engine", choices=("pybullet", "mujoco", "both"), default="pybullet")
    ap.add_argument("--tasks", default="all",
                    help=f"{', '.join(TASK_FILTERS)}, or a comma list of scene / scene:target (default all)")
    ap.add_argument("--limit", type=int, default=None, help="only the first N tasks (after --tasks)")
    ap.add_argument("--jobs", type=int, default=1, help="processes over tasks (spawned; default 1)")
    ap.add_argument("--out", default=None, help="rows (JSONL); the summary goes to <out>.md")
    ap.add_argument("--resume", action="store_true", help="keep rows already in --out made with the same settings")
    ap.add_argument("--seed", type=int, default=None,
                    help="plan seed of both plans (default: shelfpick plan's); other seeds show the draws' share")
    return ap.parse_args(argv)


def check_args(a: argparse.Namespace) -> list[str]:
    """The engines to judge with; UsageError naming a bad option and its value."""
    for name in ("limit", "jobs"):
        v = getattr(a, name)
        if v is not None and v < 1:
            raise UsageError(f"--{name}: expected a positive integer, got {v!r}")
    judge_dir = Path(a.judge_dir)
    for f in ("judge.py", "observe.py", "tasks.json", "scenes"):
        if not (judge_dir / f).exists():
            raise UsageError(f"--judge-dir: {judge_dir} has no {f} (the independent judge's folder)")
    if a.resume and not a.out:
        raise UsageError("--resume: needs --out (the rows to continue)")
    return list(ENGINES) if a.engine == "both" else [a.engine]


def task_key(task: dict) -> str:
    """A row's identity for `--resume` (with the settings id)."""
    return f"perceived|{task['scene']}:{task['target']}"


def build_units(a: argparse.Namespace, engines: list[str]) -> tuple[list[dict], str]:
    """One unit a task, shaped as judge_rows.run_unit wants it (it makes plan A), in task order so that
    a process perceives each shelf once; and the settings id rows must match to be reused."""
    judge_dir = str(Path(a.judge_dir).resolve())
    tasks = load_tasks(Path(judge_dir), a.tasks, a.limit)
    settings = cli_plan_settings({"seed": a.seed})
    settings_id = json.dumps({"plan": settings, "engines": engines, "segmenter": SEGMENTER, "camera": "frame",
                              "render_seed": "observe_seed"}, sort_keys=True)
    units = [{"task": t, "noise": 0.0, "planner": "physics", "engines": engines, "settings": settings,
              "settings_id": settings_id, "judge_dir": judge_dir} for t in tasks]
    return units, settings_id


# --------------------------------------------------------------------------
# perception of one true shelf (cached: a shelf carries 3 tasks)
@functools.cache
def _segmenter() -> Any:
    from shelfpick.perception.segment import load_segmenter

    return load_segmenter(None, SEGMENTER)


@functools.lru_cache(maxsize=2)
def perceived_shelf(judge_dir: str, scene: str) -> dict:
    """Render the judge's true shelf with a framing camera, perceive it, map perceived ids to true ids."""
    from benchmarks.perceive_plan import framing_camera, map_ids
    from shelfpick.perception.evaluation.truth import front_face_masks
    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.render import render
    from shelfpick.perception.scene import Scene

    truth = Scene.from_json(json.loads((Path(judge_dir) / "scenes" / f"{scene}.json").read_text(encoding="utf-8")),
                            f"{scene}.json")
    cam = framing_camera(truth)
    cap = render(truth, cam, seed=observe_seed(scene))
    gt = front_face_masks(truth, cap)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = perceive(cap, _segmenter(), truth.shelf)
    perceive_s = time.perf_counter() - t0
    ids = map_ids(res.masks, res.scene, gt)
    return {"res": res, "gt": gt, "ids": ids, "perceive_s": round(perceive_s, 3), "camera_y": round(cam.position[1], 3),
            "segmenter": res.segmenter, "boxes_true": len(truth.boxes), "boxes_perceived": len(res.scene.boxes),
            "true_seen": len(set(ids.values())), "perceived_unmapped": len(res.scene.boxes) - len(ids)}


def translate(sequence: Sequence[str], ids: dict[str, str]) -> tuple[list[str], list[int]]:
    """Plan B's perceived ids as true ids, step for step (the judge's step list stays aligned with the
    plan's); a perceived box mapped to no true box becomes an id the judge does not know, and its step
    index is returned as a failed step."""
    out, failed = [], []
    for i, pid in enumerate(sequence):
        tid = ids.get(pid)
        if tid is None:
            failed.append(i)
        out.append(tid if tid is not None else UNMAPPED + pid)
    return out, failed


# --------------------------------------------------------------------------
# one task (runs in a worker process)
def plan_b(unit: dict, per: dict, truth: dict) -> dict:
    """Plan on the perceived scene for the perceived target, translate to true ids, judge on the truth."""
    from benchmarks.perceive_plan import perceived_target

    task = unit["task"]
    row: dict[str, Any] = {}
    ptarget = perceived_target(per["res"], per["ids"], per["gt"], task["target"])
    row["perceived_target"] = ptarget
    if ptarget is None:
        row["error"] = "target not perceived"
        row["judges"] = {}
        return row
    fields, doc = make_timed_plan(per["res"].scene.to_json(), ptarget, unit["planner"], unit["settings"])
    row.update(fields)
    if not doc:
        row["judges"] = {}
        return row
    seq, failed = translate(doc["sequence"], per["ids"])
    row.update(perceived_sequence=row.pop("sequence"), sequence=seq, unmapped_steps=failed)
    true_doc = dict(doc, sequence=seq, target=task["target"])
    row["judges"] = {}
    for e in unit["engines"]:
        v = judged(e, truth, true_doc)
        if failed:      # the robot pulled at a box that is not there: the plan failed at that step
            v["judge_ok"], v["ok"] = v["ok"], False
        row["judges"][e] = v
    return row


def run_task(unit: dict) -> dict:
    """Plans A (judge's observation) and B (perceived render) for one task, both judged: one row."""
    task, judge_dir = unit["task"], unit["judge_dir"]
    a = run_unit(unit)
    truth = json.loads((Path(judge_dir) / "scenes" / f"{task['scene']}.json").read_text(encoding="utf-8"))
    per = perceived_shelf(judge_dir, task["scene"])
    b = {k: a[k] for k in HEADER}
    b.update(plan_b(unit, per, truth))
    shelf = {k: per[k] for k in ("camera_y", "segmenter", "perceive_s", "boxes_true", "boxes_perceived",
                                 "true_seen", "perceived_unmapped")}
    return {"key": task_key(task), "settings": unit["settings_id"], "scene": task["scene"], "target": task["target"],
            "kind": task["kind"], "target_perceived": b["perceived_target"] is not None,
            "perceived_to_true": per["ids"], **shelf, "a": a, "b": b}


def collect(rows: list[dict], todo: Sequence[dict], jobs: int, out: Path | None) -> None:
    """`judge_rows.collect_rows` over `run_task`, with a progress bar."""
    from tqdm import tqdm

    with tqdm(total=len(todo), desc="tasks", file=sys.stderr, dynamic_ncols=True) as bar:
        def shown(row: dict) -> None:
            bar.set_postfix_str(f"{row['scene']}:{row['target']} {_verdicts(row)}")
            bar.update()
        collect_rows(rows, todo, jobs, out, run_task, shown)


def _verdicts(row: dict) -> str:
    """'A ok/FAIL B ok/FAIL' per engine, as the progress bar and the differing-task list show them."""
    parts = []
    for e in ENGINES:
        if e in row["a"]["judges"] or e in row["b"]["judges"]:
            va, vb = (row[p]["judges"].get(e, {}).get("ok") for p in "ab")
            parts.append(f"{e} A {'ok' if va else 'FAIL'} B {'ok' if vb else 'FAIL'}")
    return "; ".join(parts) or row["b"].get("error", "")


# --------------------------------------------------------------------------
# summary
def summarize(rows: Sequence[dict], engines: Sequence[str]) -> dict:
    """Per engine evaluate.py's figures for A and B (judge_summary.engine_summary), perception figures
    per shelf, plan times, and the tasks where A and B differ."""
    shelves = {r["scene"]: r for r in rows}.values()
    a_rows, b_rows = [r["a"] for r in rows], [r["b"] for r in rows]
    b_planned = [r for r in b_rows if "plan_s" in r]
    times = {p: {"p50": percentile([r["plan_s"] for r in rs if "plan_s" in r], 0.5),
                 "p90": percentile([r["plan_s"] for r in rs if "plan_s" in r], 0.9)}
             for p, rs in (("a", a_rows), ("b", b_rows))}
    differ = {e: [f"{r['scene']}:{r['target']}" for r in rows
                  if bool(r["a"]["judges"].get(e, {}).get("ok")) != bool(r["b"]["judges"].get(e, {}).get("ok"))]
              for e in engines}
    return {
        "tasks": len(rows), "structured": sum(r["kind"] == "structured" for r in rows),
        "target_perceived": sum(r["target_perceived"] for r in rows),
        "b_plan_errors": sum(1 for r in b_planned if "error" in r),
        "b_unmapped_step_plans": sum(1 for r in b_planned if r.get("unmapped_steps")),
        "shelves": len(shelves), "boxes_true": sum(r["boxes_true"] for r in shelves),
        "boxes_perceived": sum(r["boxes_perceived"] for r in shelves),
        "true_seen": sum(r["true_seen"] for r in shelves),
        "perceived_unmapped": sum(r["perceived_unmapped"] for r in shelves),
        "perceive_s_p50": percentile([r["perceive_s"] for r in shelves], 0.5),
        "plan_s": times, "plan_len": {p: _mean_len(rs) for p, rs in (("a", a_rows), ("b", b_planned))},
        "engines": {e: {"a": engine_summary(a_rows, e), "b": engine_summary(b_rows, e),
                        "a_ok_b_fail": sum(1 for r in rows if r["a"]["judges"].get(e, {}).get("ok")
                                           and not r["b"]["judges"].get(e, {}).get("ok")),
                        "differ": differ[e]} for e in engines},
        "differ_rows": {f"{r['scene']}:{r['target']}": _verdicts(r) + _why(r) for r in rows
                        if any(f"{r['scene']}:{r['target']}" in d for d in differ.values())},
    }


def _mean_len(rows: Sequence[dict]) -> float:
    lens = [len(r["sequence"]) for r in rows if "sequence" in r]
    return sum(lens) / len(lens) if lens else float("nan")


def _why(row: dict) -> str:
    """What B was, in a few words: its plan next to A's, or why there is none."""
    b = row["b"]
    if "sequence" not in b:
        return f" ({b.get('error', 'no plan')})"
    extra = f", unmapped steps {b['unmapped_steps']}" if b.get("unmapped_steps") else ""
    return (f" (A {row['a'].get('sequence')} {'safe' if row['a'].get('declared_safe') else 'UNSAFE'}, "
            f"B {b['sequence']} {'safe' if b.get('declared_safe') else 'UNSAFE'}{extra})")


def to_markdown(s: dict, header: str) -> str:
    """The summary as markdown: figures, one table per engine, the differing tasks."""
    n = s["tasks"]
    t = s["plan_s"]
    lines = ["# Plans from perceived renders vs the judge's observation\n", header + "\n",
             (f"- tasks: {n} ({s['structured']} structured, {n - s['structured']} unstructured) "
              f"on {s['shelves']} shelves"),
             (f"- target perceived: {s['target_perceived']}/{n}; plans B that failed to be made: "
              f"{s['b_plan_errors']}; plans B with a step on a box that is no true box: {s['b_unmapped_step_plans']}"),
             (f"- boxes perceived / true: {s['boxes_perceived']}/{s['boxes_true']} "
              f"(true boxes a perceived box maps to: {s['true_seen']}; perceived boxes that map to none: "
              f"{s['perceived_unmapped']}); perception p50 {s['perceive_s_p50']:.2f} s a shelf"),
             (f"- plan time A p50 {t['a']['p50']:.2f} s, p90 {t['a']['p90']:.2f} s; "
              f"B p50 {t['b']['p50']:.2f} s, p90 {t['b']['p90']:.2f} s"),
             f"- boxes in the plan: A {s['plan_len']['a']:.2f}, B {s['plan_len']['b']:.2f}", "",
             "| engine | ok A | ok B | A ok, B not | B ok, A not | declared safe that collapsed A | ... B |",
             "|---|---|---|---|---|---|---|"]
    for e, v in s["engines"].items():
        a, b = v["a"], v["b"]
        lines.append(f"| {e} | {a['ok']}/{n} | {b['ok']}/{n} | {v['a_ok_b_fail']} | "
                     f"{len(v['differ']) - v['a_ok_b_fail']} | {a['declared_safe_collapsed']}/{a['declared_safe']} | "
                     f"{b['declared_safe_collapsed']}/{b['declared_safe']} |")
    lines += ["", "## Tasks where A and B differ", ""]
    lines += [f"- {k}: {v}" for k, v in s["differ_rows"].items()] or ["- none"]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------
def run(a: argparse.Namespace) -> dict:
    """Keep the rows `--resume` allows, run the rest, summarize them all."""
    engines = check_args(a)
    units, settings_id = build_units(a, engines)
    out = Path(a.out) if a.out else None
    rows = kept_rows(out, a.resume, settings_id, {task_key(u["task"]) for u in units})
    done = {r["key"] for r in rows}
    todo = [u for u in units if task_key(u["task"]) not in done]
    print(f"judge_perceived: {len(units)} tasks, engines {'+'.join(engines)}; {len(rows)} rows kept, "
          f"{len(todo)} to run on {a.jobs} process(es)", file=sys.stderr)
    t0 = time.perf_counter()
    collect(rows, todo, a.jobs, out)
    order = {task_key(u["task"]): i for i, u in enumerate(units)}
    rows.sort(key=lambda r: order[r["key"]])
    summary = summarize(rows, engines)
    summary["run"] = {"wall_s": round(time.perf_counter() - t0, 1), "jobs": a.jobs,
                      "settings": json.loads(settings_id)}
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Run, print and write the summary (<out>.md); 2 on a bad argument."""
    a = parse_args(argv)

    def header(summary: dict) -> str:
        r = summary["run"]
        return (f"judge_perceived: plan settings {json.dumps(r['settings']['plan'])}, segmenter {SEGMENTER}, "
                f"framing camera; {r['wall_s']} s on {r['jobs']} process(es)")
    md_out = Path(a.out).with_suffix(".md") if a.out else None
    return 0 if print_report("judge_perceived", run, a, header, to_markdown, md_out) is not None else 2


if __name__ == "__main__":
    sys.exit(main())
