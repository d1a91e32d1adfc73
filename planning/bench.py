"""The scalability benchmark: every box of every scene in turn is the target.

Each planner plans on the scene with depths hidden (what a camera gives) and
its plan is executed on the true scene. The unit of work is one scene (all its
pending targets). By default each target is planned from a fresh Predictor,
whose build counts as planning time (the latency an operator sees); with
`shared_predictor` one Predictor serves the whole scene. Every seed is derived from (base seed, scene
name[, target]), never from worker order, so serial, `--workers N` and Ray runs
give the same records (planning times aside). Records are appended to a JSONL
file and flushed as each scene finishes; a rerun skips the targets already
there, so a stopped run continues and no task is counted twice.
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import time
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Sequence

import numpy as np

from shelfpick.perception.errors import FormatError, SceneError, ShelfpickError
from shelfpick.perception.scene import Scene, quat_to_matrix, read_json, write_json
from shelfpick.planning.bench_config import BenchConfig, TruthModel
from shelfpick.planning.bench_report import (
    TIMING_KEYS,
    comparable,
    summarize,
    to_markdown,
    write_reports,
)
from shelfpick.planning.execute import execute_plan
from shelfpick.planning.exhaustive import min_removals, true_scene_oracle
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.planner import make_plan
from shelfpick.planning.predict import Predictor
from shelfpick.planning.sim import ShelfSim

__all__ = ["BenchConfig", "Job", "RecordLog", "TruthModel", "comparable", "derive_seed", "draw_truth",
           "observe", "read_records", "TIMING_KEYS", "run_bench", "run_scene", "summarize", "to_markdown", "true_world"]


RECORDS = "records.jsonl"
RUN_META = "run.json"


def derive_seed(*parts: Any) -> int:
    """A 31-bit seed from any parts (base seed, scene name, target): order-independent of workers."""
    h = hashlib.sha256("\x1f".join(str(p) for p in parts).encode()).digest()
    return int.from_bytes(h[:4], "big") & 0x7FFFFFFF


def scene_kind(scene_doc: dict, name: str) -> str:
    """Stack kind from the scene's `source.kind`, else from the file name, else 'other'."""
    src = scene_doc.get("source")
    if isinstance(src, dict) and isinstance(src.get("kind"), str):
        return src["kind"]
    for k in ("unstructured", "structured"):
        if k in name:
            return k
    return "other"


def scene_sha(doc: dict) -> str:
    """Identifies a scene's content: a resumed run refuses records made on a different file."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Job:
    """One scene: its JSON document (so remote workers need no shared disk) and pending targets."""

    name: str
    doc: dict
    targets: tuple[str, ...]
    config: BenchConfig


# --------------------------------------------------------------------------
# the truth: what the camera gives the planner, and the shelf the plan really meets
def observe(truth: "Scene", noise: float, seed: int, placeholder: float = 0.10) -> "Scene":
    """Front faces only: depth unknown (a placeholder), no masses, `noise` m of error
    (normal, per axis) on each front face's centre and on its width and height."""

    rng = np.random.default_rng(seed)
    out = []
    for b in truth.boxes:
        hidden = b.with_depth(placeholder)
        if noise > 0:
            r = np.array(quat_to_matrix(b.orientation))
            dc = rng.normal(0.0, noise, 3)
            dw, dh = rng.normal(0.0, noise, 2)
            front = np.array(hidden.front_center) + dc
            size = (max(0.05, b.size[0] + dw), placeholder, max(0.05, b.size[2] + dh))
            pos = front + r[:, 1] * placeholder / 2
            hidden = replace(hidden, size=size, position=tuple(float(v) for v in pos))
        out.append(replace(hidden, mass=None, depth_known=False))
    return truth.with_boxes(out)


def draw_truth(truth: "Scene", model: TruthModel, seed: int) -> tuple["Scene", "PhysicsConfig"]:
    """True masses (where the scene has none) and a truth physics, drawn from `seed`."""


    rng = np.random.default_rng(seed)
    boxes = [b if b.mass is not None else replace(b, mass=round(float(rng.uniform(*model.mass)), 3))
             for b in truth.boxes]
    config = PhysicsConfig(lateral_friction=float(rng.uniform(*model.friction)),
                           pull_speed=float(rng.uniform(*model.pull_speed)),
                           pull_force=float(rng.uniform(*model.pull_force)),
                           pull_lift=model.pull_lift, pull_hold=model.pull_hold)
    return truth.with_boxes(boxes), config


def stands(scene: "Scene", config: "PhysicsConfig", tolerance: float) -> str | None:
    """None when every box stays within `tolerance` of its place while the shelf settles and
    then rests 0.5 s under `config`; else which box moved and how far (not a truth)."""


    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            sim = ShelfSim(scene, config)
        except ShelfpickError as exc:
            return str(exc)
    try:
        gone = set(scene.ids) - set(sim.present())
        if gone:
            return f"{sorted(gone)} left the shelf"
        after = {b.id: b.position for b in sim.scene.boxes}
        drift = sim.idle(0.5)
    finally:
        sim.close()
    moved = {b.id: math.dist(b.position, after[b.id]) + drift.get(b.id, 0.0) for b in scene.boxes}
    worst = max(moved, key=moved.get)
    if moved[worst] > tolerance:
        return f"{worst} moved {moved[worst] * 100:.1f} cm"
    return None


def true_world(truth: "Scene", model: TruthModel, seed: int) -> tuple["Scene", "PhysicsConfig", int]:
    """A truth draw under which the shelf stands as it is (redrawn otherwise); (scene, physics, draw).
    SceneError when no draw of `model.draws` stands: the scene is no truth for this model."""

    why = ""
    for k in range(model.draws):
        scene, config = draw_truth(truth, model, derive_seed(seed, "truth", k))
        why = stands(scene, config, model.stand_tolerance) or ""
        if not why:
            return scene, config, k
    raise SceneError(f"the shelf does not stand under any of {model.draws} truth draws (last: {why})")


# --------------------------------------------------------------------------
# the work itself (runs in a worker)
def _worlds(job: Job) -> tuple["Scene", "Scene", "PhysicsConfig | None", dict]:
    """(what the planner is given, the truth it is judged on, the truth physics, record fields)."""

    cfg = job.config
    truth = Scene.from_json(job.doc, job.name)
    if cfg.truth is None:
        return truth.hide_depths(), truth, None, {}
    world, physics, draw = true_world(truth, cfg.truth, derive_seed(cfg.seed, job.name, "truth"))
    seen = observe(world, cfg.truth.noise, derive_seed(cfg.seed, job.name, "observe"))
    info = {"truth": {"draw": draw, "friction": round(physics.lateral_friction, 4),
                      "pull_speed": round(physics.pull_speed, 4), "pull_force": round(physics.pull_force, 2),
                      "masses": [b.mass for b in world.boxes]}}
    return seen, world, physics, info


def _plan_and_run(job: Job, seen: "Scene", truth: "Scene", physics: "PhysicsConfig | None",
                  target: str, planner: str, shared: Any, seed: int) -> dict:
    """One planner on one target: plan on what was seen (timed), execute on the truth."""

    cfg = job.config
    plan_seed = derive_seed(cfg.seed, job.name, "plan")
    t1 = time.perf_counter()
    try:
        predictor = shared or Predictor(seen, samples=cfg.samples, seed=plan_seed, model=cfg.model())
        try:
            plan = make_plan(seen, "extract", target, planner, cfg.samples, plan_seed, predictor=predictor)
        finally:
            if shared is None:
                predictor.close()
    except ShelfpickError as exc:  # the seen shelf cannot stand: no plan, so not safe and not ok
        return {"sequence": [], "safe": False, "predicted_risk": 1.0, "ok": False, "extracted": False,
                "collapsed": [], "removed": 0, "mean_disp": 0.0, "error": str(exc)[:300],
                "plan_s": time.perf_counter() - t1, "exec_wall_s": 0.0}
    plan_s = time.perf_counter() - t1
    t2 = time.perf_counter()
    ex = execute_plan(truth, plan.sequence, seed=seed, config=physics)
    steps = ex.steps
    return {"sequence": list(plan.sequence), "safe": plan.safe, "predicted_risk": round(plan.risk, 6),
            "step_risk": [round(p.risk, 4) for p in plan.predicted],
            "step_collapsed": [bool(st.collapsed) for st in steps],
            "ok": bool(ex.ok), "extracted": bool(steps and steps[-1].extracted),
            "collapsed": sorted({b for st in steps for b in st.collapsed}),
            "removed": len(plan.sequence), "mean_disp": round(ex.mean_displacement(), 6),
            "plan_s": plan_s, "exec_wall_s": time.perf_counter() - t2}


def run_scene(job: Job) -> list[dict]:
    """Plan and execute every pending target of one scene; one record per target."""


    cfg = job.config
    base = {"scene": job.name, "kind": scene_kind(job.doc, job.name), "scene_sha": scene_sha(job.doc),
            "n_boxes": len(job.doc.get("boxes", []))}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            seen, truth, physics, info = _worlds(job)
        except SceneError as exc:  # no truth: recorded (and counted) apart, never as a plan's failure
            return [dict(base, key=f"{job.name}:{t}", target=t, planners={}, no_truth=str(exc)[:300])
                    for t in job.targets]
        t0 = time.perf_counter()
        plan_seed = derive_seed(cfg.seed, job.name, "plan")
        shared = (Predictor(seen, samples=cfg.samples, seed=plan_seed, model=cfg.model())
                  if cfg.shared_predictor else None)
        setup_s = time.perf_counter() - t0
        exhaustive = None
        if len(truth.boxes) <= cfg.exhaustive_max_boxes:
            exhaustive = (min_removals, true_scene_oracle(truth, derive_seed(cfg.seed, job.name, "exhaustive"),
                                                          config=physics))
        records = []
        try:
            for target in job.targets:
                seed = derive_seed(cfg.seed, job.name, target)
                rec: dict[str, Any] = dict(base, key=f"{job.name}:{target}", target=target, seed=seed,
                                           setup_s=setup_s, planners={}, **info)
                for planner in cfg.planners:
                    rec["planners"][planner] = _plan_and_run(job, seen, truth, physics, target, planner,
                                                             shared, seed)
                if exhaustive is not None:
                    t3 = time.perf_counter()
                    best = exhaustive[0](truth.ids, target, exhaustive[1], max_boxes=max(len(truth.ids), 1))
                    rec["exhaustive"] = {"feasible": best is not None,
                                         "min_removals": None if best is None else len(best),
                                         "sequence": None if best is None else list(best)}
                    rec["exhaustive_s"] = time.perf_counter() - t3
                records.append(rec)
        finally:
            if shared is not None:
                shared.close()
            if exhaustive is not None:
                exhaustive[1].close()
    return records


# --------------------------------------------------------------------------
# input, resume
def load_jobs(scenes_dir: str | Path, config: BenchConfig, limit: int | None = None,
              done: Iterable[str] = (), shas: dict[str, str] | None = None) -> list[Job]:
    """Scene files (sorted by name) with the targets not yet in `done`; `shas` gets each scene's content id."""

    d = Path(scenes_dir)
    if not d.is_dir():
        raise FormatError(str(d), "", "not a folder of scene files")
    files = sorted(p for p in d.glob("*.json") if p.is_file())
    if not files:
        raise FormatError(str(d), "", "no scene files (*.json) in this folder")
    if limit is not None:
        files = files[:limit]
    finished = set(done)
    jobs = []
    for p in files:
        doc = read_json(p)
        scene = Scene.from_json(doc, str(p))  # validate here: a bad file fails before any work
        name = p.stem
        if shas is not None:
            shas[name] = scene_sha(doc)
        targets = tuple(t for t in scene.ids if f"{name}:{t}" not in finished)
        if targets:
            jobs.append(Job(name, doc, targets, config))
    return jobs


def count_tasks(scenes_dir: str | Path, limit: int | None = None) -> int:
    files = sorted(Path(scenes_dir).glob("*.json"))
    if limit is not None:
        files = files[:limit]
    return sum(len(Scene.load(p).boxes) for p in files)


def read_records(path: str | Path) -> list[dict]:
    """Finished records; a torn last line (crash mid-write) is dropped, duplicates keep the first."""
    p = Path(path)
    if not p.exists():
        return []
    out: dict[str, dict] = {}
    for line in p.read_text(encoding="utf-8").splitlines():
        line = line.strip()
        if not line:
            continue
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            continue
        if isinstance(rec, dict) and isinstance(rec.get("key"), str):
            out.setdefault(rec["key"], rec)
    return list(out.values())


class RecordLog:
    """Append-only JSONL; each scene's records are written and fsync'ed as soon as they arrive."""

    def __init__(self, path: str | Path):
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        # a crash can leave half a line: cut it off so the next append starts clean
        if self.path.exists():
            data = self.path.read_bytes()
            if data and not data.endswith(b"\n"):
                cut = data.rfind(b"\n") + 1
                with open(self.path, "r+b") as f:
                    f.truncate(cut)
        self._f = open(self.path, "a", encoding="utf-8")

    def write(self, records: Sequence[dict]) -> None:
        for r in records:
            self._f.write(json.dumps(r, sort_keys=True) + "\n")
        self._f.flush()
        os.fsync(self._f.fileno())

    def close(self) -> None:
        self._f.close()


def check_meta(out: Path, config: BenchConfig, scenes_dir: str | Path) -> None:
    """A rerun into the same folder must use the same settings, or the numbers would mix."""
    meta_path = out / RUN_META
    meta = {"format": "shelfpick.bench/1", "config": config.to_json(),
            "scenes": str(Path(scenes_dir).resolve())}
    if meta_path.exists():
        old = read_json(meta_path)
        if old.get("config") != meta["config"]:
            raise FormatError(str(meta_path), "config",
                              f"this folder holds a run with {old.get('config')}, not {meta['config']}; "
                              "use another --out")
        return
    write_json(meta_path, meta)


# --------------------------------------------------------------------------
# executors: each yields lists of records as scenes finish (any order)
def iter_serial(jobs: Sequence[Job], fn: Callable[[Job], list[dict]]) -> Iterator[list[dict]]:
    for job in jobs:
        yield fn(job)


def iter_workers(jobs: Sequence[Job], fn: Callable[[Job], list[dict]], workers: int) -> Iterator[list[dict]]:
    """Local worker processes (spawn: no forked PyBullet state), alive for the whole run."""
    import multiprocessing as mp

    ctx = mp.get_context("spawn")
    with ctx.Pool(processes=workers) as pool:
        # big scenes first keeps the pool busy to the end
        order = sorted(jobs, key=lambda j: -len(j.targets))
        yield from pool.imap_unordered(fn, order, chunksize=1)


def iter_ray(jobs: Sequence[Job], fn: Callable[[Job], list[dict]], address: str,
             workers: int | None = None) -> Iterator[list[dict]]:
    """Ray: one long-lived actor per worker slot; `address` is 'auto', 'local' or HOST:PORT."""
    try:
        import ray
        from ray.util import ActorPool
    except ImportError:
        raise ShelfpickError("--ray needs the 'ray' package: pip install 'shelfpick[distributed]'") from None
    started = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if address == "local":
            kwargs["num_cpus"] = workers or os.cpu_count() or 1
        else:
            kwargs["address"] = address
        # workers import the project from the driver's working directory
        kwargs["runtime_env"] = {"env_vars": {"PYTHONPATH": os.pathsep.join(
            [str(Path(__file__).resolve().parent.parent)] + [p for p in os.environ.get("PYTHONPATH", "").split(os.pathsep) if p])}}
        try:
            ray.init(**kwargs)
        except ConnectionError as exc:
            raise ShelfpickError(f"--ray {address}: cannot connect to a Ray cluster ({exc})") from None
        started = True
    try:
        n = workers or max(1, int(ray.cluster_resources().get("CPU", 1)))

        @ray.remote(num_cpus=1)
        class _Worker:
            def run(self, job: Job) -> list[dict]:
                rec = fn(job)
                return rec

        actors = [_Worker.remote() for _ in range(min(n, max(1, len(jobs))))]
        pool = ActorPool(actors)
        order = sorted(jobs, key=lambda j: -len(j.targets))
        yield from pool.map_unordered(lambda a, j: a.run.remote(j), order)
    finally:
        if started:
            ray.shutdown()


# --------------------------------------------------------------------------
def run_bench(scenes_dir: str | Path, out: str | Path, config: BenchConfig, *,
              workers: int = 1, ray_address: str | None = None, limit: int | None = None,
              fn: Callable[[Job], list[dict]] = run_scene, progress: bool = True) -> dict:
    """Run (or continue) the benchmark; write records, results.json/.md and a plot; return the summary."""
    from tqdm import tqdm

    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    check_meta(out, config, scenes_dir)
    rec_path = out / RECORDS
    old = read_records(rec_path)
    done = {r["key"] for r in old}
    shas: dict[str, str] = {}
    jobs = load_jobs(scenes_dir, config, limit, done, shas)
    for r in old:
        if r.get("scene_sha") and r["scene"] in shas and r["scene_sha"] != shas[r["scene"]]:
            raise FormatError(str(rec_path), "scene_sha",
                              f"records of scene {r['scene']!r} were made on a different file "
                              f"({r['scene_sha']} != {shas[r['scene']]}); use another --out")
    total = count_tasks(scenes_dir, limit)
    pending = sum(len(j.targets) for j in jobs)
    log = RecordLog(rec_path)
    t0 = time.perf_counter()
    try:
        if ray_address:
            it = iter_ray(jobs, fn, ray_address, workers if workers > 1 else None)
        elif workers > 1:
            it = iter_workers(jobs, fn, workers)
        else:
            it = iter_serial(jobs, fn)
        with tqdm(total=total, initial=total - pending, desc="bench", unit="task",
                  disable=not progress) as bar:
            for recs in it:
                log.write(recs)
                bar.update(len(recs))
    finally:
        log.close()
    wall = time.perf_counter() - t0
    records = read_records(rec_path)
    summary = summarize(records, config)
    summary["run"] = {"tasks": len(records), "new_tasks": pending, "wall_s": round(wall, 3),
                      "throughput_tasks_per_s": round(pending / wall, 4) if pending and wall > 0 else None,
                      "mode": f"ray:{ray_address}" if ray_address else (f"workers:{workers}" if workers > 1 else "serial")}
    write_reports(out, summary)
    return summary
