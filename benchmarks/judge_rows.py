"""The judge report's rows: which tasks, one (noise, planner, task) unit observed, planned and judged, and
the rows file written as units finish and read back for `--resume`.

The judge is not ours and is never copied: it is imported at run time from its folder (see init_worker).
"""
from __future__ import annotations

import argparse
import functools
import json
import os
import sys
import time
import warnings
from pathlib import Path
from typing import Any, Callable, Iterator, Sequence, TextIO

ROOT = Path(__file__).resolve().parent.parent
TASK_FILTERS = ("all", "exhaustive", "solvable", "unsolvable", "structured", "unstructured")


class UsageError(Exception):
    """A bad argument: one line naming it and its value, exit code 2."""


# --------------------------------------------------------------------------
# tasks
def load_tasks(judge_dir: Path, which: str, limit: int | None) -> list[dict]:
    """The judge's tasks, filtered by a kind (TASK_FILTERS) or a comma list of scene / scene:target names."""
    path = judge_dir / "tasks.json"
    try:
        tasks = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise UsageError(f"{path}: cannot read the judge's tasks ({exc})") from None
    keep = {
        "all": lambda t: True,
        "exhaustive": lambda t: t["exhaustive"],
        "solvable": lambda t: bool(t.get("min_removals")),
        "unsolvable": lambda t: t["exhaustive"] and not t.get("min_removals"),
        "structured": lambda t: t["kind"] == "structured",
        "unstructured": lambda t: t["kind"] == "unstructured",
    }.get(which)
    if keep is None:
        names = {n.strip() for n in which.split(",") if n.strip()}
        known = {t["scene"] for t in tasks} | {f"{t['scene']}:{t['target']}" for t in tasks}
        unknown = sorted(names - known)
        if unknown:
            raise UsageError(f"--tasks: unknown task {unknown[0]!r} (expected one of {', '.join(TASK_FILTERS)}, "
                             "or scene / scene:target names such as s00,u03:b2)")
        keep = lambda t: t["scene"] in names or f"{t['scene']}:{t['target']}" in names  # noqa: E731
    out = [t for t in tasks if keep(t)]
    return out[:limit] if limit is not None else out


def clear_tasks(tasks: Sequence[dict]) -> list[dict]:
    """One clearance task per shelf of `tasks` (target None: every box out), in first-seen order."""
    out: dict[str, dict] = {}
    for t in tasks:
        out.setdefault(t["scene"], {"scene": t["scene"], "target": None, "kind": t["kind"],
                                    "n_boxes": t.get("n_boxes"), "exhaustive": False, "min_removals": None})
    return list(out.values())


def observe_seed(scene: str) -> int:
    """The perception-error seed evaluate.py gives a scene (s07 / u07 -> 24)."""
    return int(scene[1:]) + 17


def row_key(noise: float, planner: str, task: dict) -> str:
    """A row's identity: what `--resume` matches on (with the settings id)."""
    return f"{noise:g}|{planner}|{task['scene']}:{task['target'] or 'clear'}"


# --------------------------------------------------------------------------
# one unit of work (runs in a worker process)
def init_worker(judge_dir: str) -> None:
    """Make the judge importable here (a spawned worker starts with a fresh sys.path)."""
    if judge_dir not in sys.path:
        sys.path.insert(0, judge_dir)
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    os.environ.setdefault("MPLBACKEND", "Agg")


@functools.cache
def judge_fn(engine: str) -> Callable[[dict, dict], dict]:
    """The judge's own entry point for an engine, imported once per process."""
    if engine == "mujoco":
        from judge_mujoco import judge_mj
        return judge_mj
    from judge import judge
    return judge


def cli_plan_settings(overrides: dict) -> dict:
    """What `shelfpick plan` passes to make_plan by default (its parser's defaults), with overrides."""
    from shelfpick.planning import cmd_plan

    parser = argparse.ArgumentParser()
    cmd_plan.add_arguments(parser)
    args = parser.parse_args(["scene.json", "--target", "x"])
    settings = {"samples": args.samples, "seed": args.seed, "risk": args.risk,
                "budget_s": args.budget, "workers": args.workers or 1, "verify": args.verify}  # None: the CLI picks by cores; --jobs already uses them
    settings.update({k: v for k, v in overrides.items() if v is not None})
    return settings


def make_timed_plan(obs: dict, target: str | None, planner: str, settings: dict) -> tuple[dict, dict]:
    """make_plan on the observed scene, in this process; (plan fields for the row, plan document)."""
    from shelfpick.perception.errors import ShelfpickError
    from shelfpick.perception.scene import Scene
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.planner import make_plan

    settings = dict(settings)
    if settings.get("physics"):
        settings["config"] = PhysicsConfig(**settings.pop("physics"))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        t0 = time.perf_counter()
        try:
            plan = make_plan(Scene.from_json(obs, "observed"), "extract" if target else "clear", target,
                             planner=planner, **settings)
        except ShelfpickError as exc:
            return {"plan_s": round(time.perf_counter() - t0, 4), "error": str(exc)[:300]}, {}
        plan_s = time.perf_counter() - t0
    check = plan.extra.get("scene_check") if isinstance(plan.extra, dict) else None
    fields = {"plan_s": round(plan_s, 4), "sequence": list(plan.sequence), "declared_safe": bool(plan.safe),
              "risk": round(plan.risk, 4),
              "step_risk": [round(p.risk, 4) for p in plan.predicted],
              "step_collapse_prob": [round(p.collapse_prob, 4) for p in plan.predicted],
              "warnings": [str(w.message)[:200] for w in caught][:5]}
    if isinstance(check, dict) and "stands_as_seen" in check:
        fields["stands_as_seen"] = bool(check["stands_as_seen"])
    search = plan.extra.get("search") if isinstance(plan.extra, dict) else None
    if isinstance(search, dict) and "success_prob" in search:   # the plan's chance that nothing goes wrong
        fields["success_prob"] = round(float(search["success_prob"]), 4)
    gated = search.get("plan_risk") if isinstance(search, dict) else None
    if isinstance(gated, dict) and "worlds" in gated:   # the gate's evidence: failing worlds of those asked
        fields["gate"] = {k: gated[k] for k in ("failed_worlds", "worlds", "probability", "high", "max_plan_risk")
                         if k in gated}
    return fields, plan.to_json()


def judged(engine: str, truth: dict, plan_doc: dict) -> dict:
    """The judge's verdict, kept to what the report needs (per-step collapse for reliability)."""
    t0 = time.perf_counter()
    v = judge_fn(engine)(truth, plan_doc)
    return {"ok": bool(v["ok"]), "first_collapse_step": v.get("first_collapse_step"),
            "n_removed": v.get("n_removed"),
            "step_collapse": [bool(s.get("collapse")) for s in v.get("steps", [])],
            "step_moved": [list(s.get("moved", [])) for s in v.get("steps", [])],
            "judge_s": round(time.perf_counter() - t0, 3)}


def run_unit(unit: dict) -> dict:
    """Observe, plan (timed), judge with every engine asked for: one row."""
    from observe import observed

    task, noise, planner = unit["task"], unit["noise"], unit["planner"]
    judge_dir = Path(unit["judge_dir"])
    truth = json.loads((judge_dir / "scenes" / f"{task['scene']}.json").read_text(encoding="utf-8"))
    # --see-truth: the planner is handed the true shelf itself (a diagnostic ceiling, not a result)
    obs = truth if unit.get("see_truth") else observed(truth, noise=noise, seed=observe_seed(task["scene"]))
    row: dict[str, Any] = {
        "key": row_key(noise, planner, task), "scene": task["scene"], "target": task["target"],
        "kind": task["kind"], "n_boxes": task.get("n_boxes"), "noise": noise, "planner": planner,
        "exhaustive": task["exhaustive"],
        "min_removals": len(task["min_removals"]) if task.get("min_removals") else None,
        "settings": unit["settings_id"]}
    fields, plan_doc = make_timed_plan(obs, task["target"], planner, unit["settings"])
    row.update(fields)
    row["judges"] = {e: judged(e, truth, plan_doc) for e in unit["engines"]} if plan_doc else {}
    return row


def init_and_run(unit: dict) -> dict:
    """run_unit in this process, the judge made importable first."""
    init_worker(unit["judge_dir"])
    return run_unit(unit)


# --------------------------------------------------------------------------
# rows: write, resume
def read_rows(path: Path) -> list[dict]:
    """Rows already written; a torn last line is dropped, a repeated key keeps the last."""
    if not path.exists():
        return []
    rows: dict[str, dict] = {}
    for line in path.read_text(encoding="utf-8").splitlines():
        try:
            r = json.loads(line)
        except ValueError:
            continue
        if isinstance(r, dict) and isinstance(r.get("key"), str):
            rows[r["key"]] = r
    return list(rows.values())


def kept_rows(out: Path | None, resume: bool, settings_id: str, wanted: set[str]) -> list[dict]:
    """The rows in `out` that `--resume` keeps: made with the same settings, for a wanted key."""
    if not (out and resume):
        return []
    return [r for r in read_rows(out) if r.get("settings") == settings_id and r["key"] in wanted]


def iter_rows(units: Sequence[dict], jobs: int, work: Callable[[dict], dict] | None = None) -> Iterator[dict]:
    """Rows as units finish: in this process, or in `jobs` spawned processes (no forked PyBullet).
    `work` (default run_unit; an importable module-level function) makes one unit's row."""
    work = work or run_unit
    if jobs <= 1:
        for u in units:
            init_worker(u["judge_dir"])
            yield work(u)
        return
    import multiprocessing as mp

    with mp.get_context("spawn").Pool(jobs, initializer=init_worker, initargs=(units[0]["judge_dir"],)) as pool:
        yield from pool.imap_unordered(work, units, chunksize=1)


def _write(f: TextIO | None, row: dict) -> None:
    if f:
        f.write(json.dumps(row) + "\n")
        f.flush()


def print_report(prog: str, run: Callable[[Any], dict], a: Any, header: Callable[[dict], str],
                 to_markdown: Callable[[dict, str], str], md_out: Path | None) -> dict | None:
    """Run a judge benchmark (`run(a)`), print its markdown report and write it to `md_out`; on a
    bad argument, one line naming it and None (the caller exits 2)."""
    try:
        summary = run(a)
    except UsageError as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return None
    text = to_markdown(summary, header(summary))
    print(text, end="")
    if md_out:
        md_out.write_text(text, encoding="utf-8")
    return summary


def collect_rows(rows: list[dict], todo: Sequence[dict], jobs: int, out: Path | None,
                 work: Callable[[dict], dict] | None = None,
                 on_row: Callable[[dict], None] | None = None) -> None:
    """Run `todo` (`work`, default run_unit), appending each row to `rows` as it finishes; `out`
    (when given) is rewritten with the kept rows first and gets every new row flushed at once, so
    a stopped run can be resumed. `on_row(row)` shows progress (default: a line per row)."""
    count = iter(range(1, len(todo) + 1))

    def line(row: dict) -> None:
        oks = " ".join(f"{e}={'ok' if v['ok'] else 'FAIL'}" for e, v in row["judges"].items())
        print(f"[{next(count)}/{len(todo)}] {row['key']} plan {row['plan_s']:.2f}s "
              f"{'safe' if row.get('declared_safe') else 'UNSAFE'} {oks or row.get('error', '')}",
              file=sys.stderr, flush=True)
    on_row = on_row or line
    f = None
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        f = open(out, "w", encoding="utf-8")
        for r in rows:
            f.write(json.dumps(r) + "\n")
        f.flush()
    try:
        for row in iter_rows(todo, jobs, work) if todo else ():
            rows.append(row)
            _write(f, row)
            on_row(row)
    finally:
        if f:
            f.close()
