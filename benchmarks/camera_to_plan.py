"""From the camera to a plan that holds (issue 31, item 3): image -> `shelfpick perceive` -> plan -> judge.

For each held-out look of `benchmarks/generators` (docs/perception.md, "Roles") and each of the
judge's true shelves (../shared/judge/scenes, imported at run time, never copied):

1. the shelf is rendered by the generator into a capture folder (rgb.png, depth.png, camera.json);
2. `shelfpick perceive` (the CLI, in a subprocess, default segmenter) writes the perceived scene;
3. perceived boxes are matched one to one to true boxes by FRONT-FACE POSITION (nearest front-face
   centres first; a pair counts when the centres are closer than half the true face's smaller side);
   segmentation figures: recall over true fronts with >= VISIBLE_PX visible pixels, precision over
   perceived boxes, front-face centre error (3-D) of matched pairs;
4. for each of the judge's tasks on that shelf, the perceived box matched to the target is planned
   with `shelfpick plan`'s defaults twice: the physics planner (B) and highest-first (`--planner
   heuristic`, H), and the plan's perceived ids are translated to true ids (a step on a perceived box
   matched to no true box fails the plan); both are judged on the TRUE shelf;
5. once per task (not per look): the same task planned on the true faces with 1 cm of error
   (`observe.py --noise 0.01`, as evaluate.py does, physics planner), judged the same way (T).

    .venv/bin/python benchmarks/camera_to_plan.py --out /tmp/c2p/rows.jsonl              # everything
    .venv/bin/python benchmarks/camera_to_plan.py --plan-shelves 5 --out /tmp/c2p/rows.jsonl --resume

`--plan-shelves N` plans only on the first N shelves of each kind (s.., u..); segmentation figures
always cover every shelf of `--shelves`. Rows (one JSON line each, flushed) go to `--out`, the summary
to `<out>.md` (also printed).
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any, Sequence

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import (UsageError, cli_plan_settings, collect_rows, init_worker, judged,  # noqa: E402
                                   kept_rows, make_timed_plan, print_report, run_unit)
from benchmarks.judge_summary import engine_summary, percentile  # noqa: E402

HELD_OUT = ("printed", "stereo")          # docs/perception.md, "Roles": never tuned on
VISIBLE_PX = 300                           # a true front with fewer visible pixels is not counted in recall
FRAME_SEED = 0
UNMAPPED = "unmapped:"


# --------------------------------------------------------------------------
# arguments
def parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    """The command line (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--looks", default=",".join(HELD_OUT), help="comma list of generator looks (default the held-out ones)")
    ap.add_argument("--shelves", default="all", help="all, or a comma list of the judge's shelves (s00,u03)")
    ap.add_argument("--plan-shelves", type=int, default=None,
                    help="plan only on the first N shelves of each kind (default: every shelf)")
    ap.add_argument("--max-tasks", type=int, default=None, help="at most N of the judge's tasks a planned shelf")
    ap.add_argument("--engine", choices=("pybullet", "mujoco"), default="pybullet")
    ap.add_argument("--frames", default=None, help="capture folders (default <out>.frames, or a temporary folder)")
    ap.add_argument("--shelfpick", default=None, help="the shelfpick command (default: beside this Python)")
    ap.add_argument("--out", default=None, help="rows (JSONL); the summary goes to <out>.md")
    ap.add_argument("--resume", action="store_true", help="keep rows already in --out made with the same settings")
    ap.add_argument("--no-true", action="store_true", help="skip the plans on the true faces (T)")
    ap.add_argument("--summary-only", action="store_true",
                    help="run nothing: summarize the rows in --out made with these settings for the units asked for")
    return ap.parse_args(argv)


def judge_shelves(judge: Path, text: str) -> list[str]:
    """The judge's shelves `--shelves` names (`all`, or a comma list); UsageError naming one it lacks."""
    have = sorted(p.stem for p in (judge / "scenes").glob("*.json"))
    shelves = have if text == "all" else [s.strip() for s in text.split(",") if s.strip()]
    unknown = [s for s in shelves if s not in have]
    if unknown or not shelves and text != "all":
        raise UsageError(f"--shelves: unknown shelf {unknown[0] if unknown else text!r} (the judge has "
                         + (f"{have[0]}..{have[-1]})" if have else "none)"))
    return shelves


def check_args(a: argparse.Namespace) -> tuple[list[str], list[str], Path]:
    """(looks, shelves, frames folder); UsageError naming a bad option and its value."""
    from benchmarks.generators import LOOK_NAMES

    looks = [s.strip() for s in a.looks.split(",") if s.strip()]
    bad = [lk for lk in looks if lk not in LOOK_NAMES]
    if bad or not looks:
        raise UsageError(f"--looks: unknown look {bad[0] if bad else a.looks!r} (expected {', '.join(LOOK_NAMES)})")
    judge = Path(a.judge_dir)
    for f in ("judge.py", "observe.py", "tasks.json", "scenes"):
        if not (judge / f).exists():
            raise UsageError(f"--judge-dir: {judge} has no {f} (the independent judge's folder)")
    shelves = judge_shelves(judge, a.shelves)
    for name in ("plan_shelves", "max_tasks"):
        v = getattr(a, name)
        if v is not None and v < 0:
            raise UsageError(f"--{name.replace('_', '-')}: expected a count >= 0, got {v}")
    if (a.resume or a.summary_only) and not a.out:
        raise UsageError(f"--{'resume' if a.resume else 'summary-only'}: needs --out (the rows to read)")
    frames = Path(a.frames) if a.frames else (Path(a.out).with_suffix(".frames") if a.out else
                                             Path(os.environ.get("TMPDIR", "/tmp")) / "camera_to_plan_frames")
    return looks, shelves, frames


def plan_shelves(shelves: Sequence[str], n: int | None) -> list[str]:
    """The first n shelves of each kind (by the name's letter), in the given order."""
    if n is None:
        return list(shelves)
    out, seen = [], {}
    for s in shelves:
        seen[s[0]] = seen.get(s[0], 0) + 1
        if seen[s[0]] <= n:
            out.append(s)
    return out


# --------------------------------------------------------------------------
# one shelf seen by one look
def shelfpick_cmd(given: str | None) -> list[str]:
    """The CLI to run: --shelfpick, else `shelfpick` beside this interpreter, else on PATH."""
    if given:
        return [given]
    beside = Path(sys.executable).with_name("shelfpick")
    return [str(beside)] if beside.exists() else ["shelfpick"]


def front_centres(scene: dict) -> dict[str, tuple]:
    """Box id -> (front-face centre (3,), smaller side of the front face) of a scene document."""
    import numpy as np

    from benchmarks.generators.raycast import rot_of

    out = {}
    for b in scene["boxes"]:
        r = rot_of(b.get("orientation", [1, 0, 0, 0]))
        out[b["id"]] = (np.array(b["position"], float) - r[:, 1] * b["size"][1] / 2, min(b["size"][0], b["size"][2]))
    return out


def match_fronts(perceived: dict, truth: dict) -> dict[str, tuple[str, float]]:
    """Perceived id -> (true id, centre distance m), one to one, nearest front-face centres first; a pair
    counts when its centres are closer than half the true face's smaller side."""
    import numpy as np

    pc, tc = front_centres(perceived), front_centres(truth)
    pairs = sorted((float(np.linalg.norm(p[0] - t[0])), pid, tid) for pid, p in pc.items() for tid, t in tc.items())
    out: dict[str, tuple[str, float]] = {}
    used: set[str] = set()
    for d, pid, tid in pairs:
        if pid in out or tid in used or d >= tc[tid][1] / 2:
            continue
        out[pid] = (tid, d)
        used.add(tid)
    return out


def visible_fronts(truth: dict, folder: Path) -> dict[str, int]:
    """True box id -> visible front-face pixels in the generated frame (its ground-truth masks)."""
    import cv2

    from shelfpick.perception.evaluation.truth import front_face_masks
    from shelfpick.perception.capture import Capture
    from shelfpick.perception.scene import Camera, Scene

    cam = Camera.from_json(json.loads((folder / "camera.json").read_text()))
    masks = cv2.imread(str(folder / "masks.png"), cv2.IMREAD_UNCHANGED)
    labels = {int(k): v for k, v in json.loads((folder / "masks.json").read_text()).items()}
    rgb = cv2.cvtColor(cv2.imread(str(folder / "rgb.png")), cv2.COLOR_BGR2RGB)
    cap = Capture(rgb, None, cam, masks, labels)
    return {k: int(m.sum()) for k, m in front_face_masks(Scene.from_json(truth, "truth"), cap).items()}


def perceive_cli(cmd: list[str], folder: Path) -> tuple[dict | None, dict, str]:
    """(perceived scene or None, report, error): `shelfpick perceive` on a capture folder."""
    out, report = folder / "perceived.json", folder / "report.json"
    for p in (out, report):
        p.unlink(missing_ok=True)
    argv = cmd + ["perceive", "--rgb", str(folder / "rgb.png"), "--depth", str(folder / "depth.png"),
                  "--camera", str(folder / "camera.json"), "--out", str(out), "--report", str(report),
                  "--masks", str(folder / "perceived_masks.png"), "--overlay", str(folder / "overlay.png")]
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "1"))
    p = subprocess.run(argv, capture_output=True, text=True, env=env, timeout=600)
    if p.returncode != 0 or not out.exists():
        lines = (p.stderr or p.stdout).strip().splitlines()
        return None, {}, f"perceive exit {p.returncode}: {lines[-1] if lines else ''}"[:300]
    return json.loads(out.read_text()), json.loads(report.read_text()), ""


@functools.lru_cache(maxsize=2)
def seen_shelf(look: str, scene: str, judge_dir: str, frames: str, shelfpick: str | None) -> dict:
    """Render (unless the folder has it), perceive, match: the shelf's segmentation figures and id map."""
    from benchmarks.generators import write_frame

    truth = json.loads((Path(judge_dir) / "scenes" / f"{scene}.json").read_text(encoding="utf-8"))
    folder = Path(frames) / look / scene
    meta = folder / "meta.json"
    if not meta.exists() or json.loads(meta.read_text()).get("seed") != FRAME_SEED:
        write_frame(truth, look, FRAME_SEED, folder, scene)
    visible = visible_fronts(truth, folder)
    perceived, report, err = perceive_cli(shelfpick_cmd(shelfpick), folder)
    counted = {k for k, n in visible.items() if n >= VISIBLE_PX}
    out: dict[str, Any] = {"look": look, "scene": scene, "true_fronts": len(counted), "error": err}
    if perceived is None:
        return dict(out, perceived=0, matched_true=0, matched=0, centre_err=[], ids={}, scene_doc=None)
    m = match_fronts(perceived, truth)
    return dict(out, perceived=len(perceived["boxes"]), matched=len(m),
                matched_true=sum(1 for t, _ in m.values() if t in counted),
                centre_err=[round(d, 4) for _, d in m.values()], ids={p: t for p, (t, _) in m.items()},
                perceive_s=report.get("timing", {}).get("total"), warnings=len(report.get("warnings", [])),
                scene_doc=perceived)


# --------------------------------------------------------------------------
# plans
def translate(sequence: Sequence[str], ids: dict[str, str]) -> tuple[list[str], list[int]]:
    """Perceived ids as true ids, step for step; steps on a box matched to no true box are returned."""
    out, failed = [], []
    for i, pid in enumerate(sequence):
        tid = ids.get(pid)
        if tid is None:
            failed.append(i)
        out.append(tid if tid is not None else UNMAPPED + pid)
    return out, failed


def plan_from_image(shelf: dict, task: dict, planner: str, settings: dict, engine: str, truth: dict) -> dict:
    """Plan for the perceived box matched to the target; translated and judged on the true shelf."""
    row: dict[str, Any] = {"exhaustive": task["exhaustive"], "kind": task["kind"],
                           "min_removals": len(task["min_removals"]) if task.get("min_removals") else None}
    ptarget = next((p for p, t in shelf["ids"].items() if t == task["target"]), None)
    row["perceived_target"] = ptarget
    if ptarget is None or shelf["scene_doc"] is None:
        return dict(row, error="target not perceived", judges={})
    fields, doc = make_timed_plan(shelf["scene_doc"], ptarget, planner, settings)
    row.update(fields)
    if not doc:
        return dict(row, judges={})
    seq, failed = translate(doc["sequence"], shelf["ids"])
    row.update(perceived_sequence=row.pop("sequence"), sequence=seq, unmapped_steps=failed)
    v = judged(engine, truth, dict(doc, sequence=seq, target=task["target"]))
    if failed:          # the robot pulled at a box that is not there: the plan failed at that step
        v["judge_ok"], v["ok"] = v["ok"], False
    row["judges"] = {engine: v}
    return row


def run_item(unit: dict) -> dict:
    """One unit: a shelf seen by a look (segmentation, and its tasks' B and H plans), or a task on true faces."""
    init_worker(unit["judge_dir"])
    if unit["what"] == "true":
        t = unit["task"]
        a = run_unit({"task": t, "noise": 0.01, "planner": "physics", "engines": [unit["engine"]],
                      "settings": unit["settings"], "settings_id": unit["settings_id"], "judge_dir": unit["judge_dir"]})
        return {"key": unit["key"], "settings": unit["settings_id"], "what": "true", "scene": t["scene"],
                "target": t["target"], "plan": a}
    shelf = seen_shelf(unit["look"], unit["scene"], unit["judge_dir"], unit["frames"], unit["shelfpick"])
    truth = json.loads((Path(unit["judge_dir"]) / "scenes" / f"{unit['scene']}.json").read_text(encoding="utf-8"))
    row = {"key": unit["key"], "settings": unit["settings_id"], "what": "seen", "look": unit["look"],
           "scene": unit["scene"], "shelf": {k: v for k, v in shelf.items() if k != "scene_doc"}, "tasks": []}
    for t in unit["tasks"]:
        plans = {p: plan_from_image(shelf, t, planner, unit["settings"], unit["engine"], truth)
                 for p, planner in (("physics", "physics"), ("highest_first", "heuristic"))}
        row["tasks"].append({"target": t["target"], **plans})
    return row


def build_units(a: argparse.Namespace, looks: list[str], shelves: list[str], frames: Path) -> tuple[list[dict], str]:
    """Units in run order (every look's shelves, then the true-face plans) and the settings id."""
    judge_dir = str(Path(a.judge_dir).resolve())
    tasks = json.loads((Path(judge_dir) / "tasks.json").read_text(encoding="utf-8"))
    planned = set(plan_shelves(shelves, a.plan_shelves))
    settings = cli_plan_settings({})
    sid = json.dumps({"plan": settings, "engine": a.engine, "frame_seed": FRAME_SEED, "visible_px": VISIBLE_PX,
                      "max_tasks": a.max_tasks},
                     sort_keys=True)
    base = {"judge_dir": judge_dir, "engine": a.engine, "settings": settings, "settings_id": sid}
    def seen(lk: str, s: str) -> dict:
        return dict(base, what="seen", look=lk, scene=s, key=f"seen|{lk}|{s}", frames=str(frames),
                    shelfpick=a.shelfpick,
                    tasks=[t for t in tasks if t["scene"] == s and s in planned][:a.max_tasks])
    # planned shelves first (and their true-face plans), so that a stopped run has whole figures
    units = [seen(lk, s) for s in shelves if s in planned for lk in looks]
    if not a.no_true:
        units += [dict(base, what="true", task=t, key=f"true|{t['scene']}:{t['target']}")
                  for u in units if u["look"] == looks[0] for t in u["tasks"]]
    units += [seen(lk, s) for s in shelves if s not in planned for lk in looks]
    return units, sid


# --------------------------------------------------------------------------
# summary
def _plan_rows(rows: Sequence[dict], look: str, which: str) -> list[dict]:
    return [t[which] for r in rows if r["what"] == "seen" and r["look"] == look for t in r["tasks"]]


CAN_HOLD = ROOT / "benchmarks" / "data" / "judge-can-hold.json"


@functools.cache
def can_hold() -> frozenset[str]:
    """The judge's tasks some plan is known to hold on the true shelf ("s00:b4"; its `about` says how)."""
    return frozenset(json.loads(CAN_HOLD.read_text(encoding="utf-8"))["tasks"])


def _held_where_possible(rows: Sequence[dict], look: str, which: str, engine: str) -> list[int]:
    """[ok, tasks] over the look's planned tasks that some plan can hold."""
    got = [bool(t[which].get("judges", {}).get(engine, {}).get("ok"))
           for r in rows if r["what"] == "seen" and r["look"] == look for t in r["tasks"]
           if f"{r['scene']}:{t['target']}" in can_hold()]
    return [sum(got), len(got)]


def summarize(rows: Sequence[dict], engine: str) -> dict:
    """Per look: segmentation figures and the judged plans (B, H); T once; over the planned tasks."""
    true_rows = {f"{r['scene']}:{r['target']}": r["plan"] for r in rows if r["what"] == "true"}
    out: dict[str, Any] = {"looks": {}, "true": engine_summary(list(true_rows.values()), engine)}
    for look in sorted({r["look"] for r in rows if r["what"] == "seen"}):
        shelves = [r["shelf"] for r in rows if r["what"] == "seen" and r["look"] == look]
        errs = sorted(e for s in shelves for e in s["centre_err"])
        fronts, perceived = sum(s["true_fronts"] for s in shelves), sum(s["perceived"] for s in shelves)
        seg = {"shelves": len(shelves), "true_fronts": fronts, "perceived": perceived,
               "recall": sum(s["matched_true"] for s in shelves) / fronts if fronts else float("nan"),
               "precision": sum(s["matched"] for s in shelves) / perceived if perceived else float("nan"),
               "centre_median_cm": 100 * percentile(errs, 0.5) if errs else float("nan"),
               "perceive_p50_s": percentile([s["perceive_s"] for s in shelves if s.get("perceive_s")], 0.5),
               "perceive_errors": sum(1 for s in shelves if s["error"])}
        plans = {p: engine_summary(_plan_rows(rows, look, p), engine) for p in ("physics", "highest_first")}
        tasks = [(r["scene"], t["target"]) for r in rows if r["what"] == "seen" and r["look"] == look for t in r["tasks"]]
        t_same = [true_rows[f"{s}:{t}"] for s, t in tasks if f"{s}:{t}" in true_rows]
        t_can = [bool(true_rows[f"{s}:{t}"].get("judges", {}).get(engine, {}).get("ok"))
                 for s, t in tasks if f"{s}:{t}" in true_rows and f"{s}:{t}" in can_hold()]
        out["looks"][look] = {"seg": seg, "plans": plans, "true_same": engine_summary(t_same, engine),
                              "can_hold": {p: _held_where_possible(rows, look, p, engine) for p in ("physics", "highest_first")}
                              | {"true": [sum(t_can), len(t_can)]},
                              "not_perceived": sum(1 for r in _plan_rows(rows, look, "physics")
                                                   if r.get("error") == "target not perceived")}
    return out


def _ok(s: dict) -> str:
    pct = lambda a, b: f"{100 * a / b:.0f}%" if b else "-"  # noqa: E731
    return (f"{s['ok']}/{s['tasks']} ({pct(s['ok'], s['tasks'])}); solvable {s['solvable_ok']}/{s['solvable']} "
            f"({pct(s['solvable_ok'], s['solvable'])})")


def to_markdown(s: dict, header: str) -> str:
    """Per look: a segmentation line and the plans table."""
    lines = ["# From the camera to a plan that holds (held-out generator looks)\n", header + "\n"]
    for look, v in s["looks"].items():
        g = v["seg"]
        lines += [f"## look `{look}`\n",
                  (f"- segmentation on {g['shelves']} shelves: recall {g['recall']:.3f} ({g['true_fronts']} true fronts "
                   f">= {VISIBLE_PX} px), precision {g['precision']:.3f} ({g['perceived']} perceived), front-face "
                   f"centre median {g['centre_median_cm']:.2f} cm; perceive p50 {g['perceive_p50_s'] or float('nan'):.2f} s "
                   f"(in-process, from the report); perceive failures {g['perceive_errors']}"),
                  f"- targets never perceived: {v['not_perceived']}", "",
                  "| plan | ok (all tasks; exhaustively solvable) | declared safe that collapsed | plan errors |",
                  "|---|---|---|---|"]
        for name, p in (("from the image, physics", v["plans"]["physics"]),
                        ("from the image, highest-first", v["plans"]["highest_first"]),
                        ("true faces + 1 cm (observe --noise 0.01), physics", v["true_same"])):
            lines.append(f"| {name} | {_ok(p)} | {p['declared_safe_collapsed']}/{p['declared_safe']} | {p['plan_errors']} |")
        c = v["can_hold"]
        pct = lambda a, b: f"{100 * a / b:.0f}%" if b else "-"  # noqa: E731
        lines += ["", f"- of the {c['physics'][1]} tasks some plan can hold on the true shelf "
                      f"(`{CAN_HOLD.relative_to(ROOT)}`): physics from the image {c['physics'][0]} "
                      f"({pct(*c['physics'])}), highest-first {c['highest_first'][0]} ({pct(*c['highest_first'])}), "
                      f"true faces + 1 cm {c['true'][0]}/{c['true'][1]} ({pct(*c['true'])})"]
        lines.append("")
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------
def run(a: argparse.Namespace) -> dict:
    """Keep the rows `--resume` allows, run the rest in this process, summarize them all."""
    looks, shelves, frames = check_args(a)
    units, sid = build_units(a, looks, shelves, frames)
    out = Path(a.out) if a.out else None
    rows = kept_rows(out, a.resume or a.summary_only, sid, {u["key"] for u in units})
    # a shelf seen without plans is not kept where its tasks are now asked for (a larger --plan-shelves)
    want = {u["key"]: [t["target"] for t in u["tasks"]] for u in units if u["what"] == "seen"}
    rows = [r for r in rows if r["what"] != "seen" or [t["target"] for t in r["tasks"]] == want[r["key"]]]
    done = {r["key"] for r in rows}
    todo = [] if a.summary_only else [u for u in units if u["key"] not in done]
    print(f"camera_to_plan: {len(units)} units ({len(rows)} kept, {len(todo)} to run); looks {looks}; "
          f"{len(shelves)} shelves, planning on {len(plan_shelves(shelves, a.plan_shelves))}", file=sys.stderr)
    t0 = time.perf_counter()

    def line(row: dict) -> None:
        print(f"[{len(rows) - kept}/{len(todo)}] {row['key']} {time.perf_counter() - t0:.0f}s",
              file=sys.stderr, flush=True)
    kept = len(rows)
    if not a.summary_only:
        collect_rows(rows, todo, 1, out, work=run_item, on_row=line)
    summary = summarize(rows, a.engine)
    summary["run"] = {"wall_s": round(time.perf_counter() - t0, 1), "settings": json.loads(sid),
                      "shelves": shelves, "planned": plan_shelves(shelves, a.plan_shelves)}
    return summary


def main(argv: Sequence[str] | None = None) -> int:
    """Run, print and write the summary (<out>.md); 2 on a bad argument."""
    a = parse_args(argv)

    def header(summary: dict) -> str:
        r = summary["run"]
        return (f"camera_to_plan: `shelfpick perceive` (default segmenter) -> plan (`shelfpick plan` defaults) -> "
                f"{a.engine} judge on the true shelf; segmentation on {len(r['shelves'])} shelves, plans on "
                f"{', '.join(r['planned']) or 'none'}; {r['wall_s']} s")
    md_out = Path(a.out).with_suffix(".md") if a.out and not a.summary_only else None
    return 0 if print_report("camera_to_plan", run, a, header, to_markdown, md_out) is not None else 2


if __name__ == "__main__":
    sys.exit(main())
