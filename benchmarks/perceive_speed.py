"""How long `perceive` takes on a 640x480 RGB-D frame (issue 31: p50 <= 0.5 s on 2 cores, held-out frames).

Frames: the generator looks of `benchmarks/generators` (docs/perception.md, "Roles"), 640x480 at frame
seed 0, written once to `--frames` and reused (generation time is not counted):
`--set held_out` (default): looks `printed` and `stereo` on the judge's 40 shelves (../shared/judge/scenes,
read at run time, never copied); `--set tune`: look `flat` (or `--tune-look labels`) on the tuning shelves 31000-31059
(`planning.shelves.generate`, as benchmarks/perceive_generated.py makes them). Held-out frames are only
timed here: nothing in their output is read.

Two ways a user meets `perceive`:

- `--mode cli`: `shelfpick perceive` end to end, one process per frame (start-up, imports, model
  load, perceive, writing the scene, overlay, masks and report), as camera_to_plan.py runs it; wall
  time and the child's CPU time (user + sys, `resource.RUSAGE_CHILDREN`);
- `--mode inproc`: `perception.pipeline.perceive` in this process with the segmenter loaded once and
  one warm-up frame first (the console's case), then the same four files written; per stage wall and
  CPU time (`time.process_time`, less sensitive to the other jobs on a shared machine). Stages are
  the functions tapped in `STAGES`, each timed exclusive of the tapped stages it calls, so the stages
  and `other` add up to the frame.

- `--mode split`: a process per frame as `--mode cli`, but `benchmarks/perceive_startup.py` does the
  CLI's work with a time stamp per phase (interpreter start, imports, reading, the ONNX session, the
  first forward pass, the rest of perceive, writing, the interpreter's exit), where the 1.5 s of a
  `shelfpick perceive` process go.

`--pycache DIR` (cli, split): the timed processes keep their bytecode in DIR (outside the repo), as an
installed package does, even where PYTHONDONTWRITEBYTECODE is set (then, without it, every process
compiles the repo's own modules from source again); one untimed process fills it first.

`--ab-tree TREE` (cli, split): before and after frame by frame, a process each, which goes first
alternating: TREE is a whole other commit (`git archive COMMIT | tar -x -C TREE`), imported as
`shelfpick` through a folder of links ahead of the installed package (so a change to console/cli.py
is timed too, not only perception's):

    git archive COMMIT | tar -x -C /tmp/ps/old
    .venv/bin/python benchmarks/perceive_speed.py --mode cli --frames /tmp/ps/frames --pycache /tmp/ps/pyc --ab-tree /tmp/ps/old

`--ab-pycache` (cli, split, with `--pycache DIR`): the same frame by frame, the working tree's code on
both sides, before under PYTHONDONTWRITEBYTECODE (a checkout without __pycache__ compiles its modules
in every process), after with the bytecode cache.

`uptime`'s load is printed before and after: the machine is shared, wall times move with it.

    .venv/bin/python benchmarks/perceive_speed.py --mode inproc --frames /tmp/ps/frames
    .venv/bin/python benchmarks/perceive_speed.py --mode cli --frames /tmp/ps/frames
    .venv/bin/python benchmarks/perceive_speed.py --mode split --frames /tmp/ps/frames --pycache /tmp/ps/pyc
    .venv/bin/python benchmarks/perceive_speed.py --set tune --fingerprint /tmp/ps/fp-before.json --frames /tmp/ps/frames
    .venv/bin/python benchmarks/perceive_speed.py --compare /tmp/ps/fp-before.json /tmp/ps/fp-after.json

`--perception-from DIR` times another commit's perception (the "before" of a change) in place of
the working tree's, in process or, with `--mode cli`, as `shelfpick` run by this script:

    git archive b8f5da2 perception | tar -x -C /tmp/old && ln -s $PWD/static /tmp/old/static
    .venv/bin/python benchmarks/perceive_speed.py --mode inproc --perception-from /tmp/old/perception

`--ab-with DIR` times both frame by frame: two warm processes (DIR's perception and the tree's) take
turns on every frame, never at once, the first alternating; both tables and the median over frames
of after / before. On a shared machine two whole runs one after the other see different loads.

`--fingerprint OUT` writes, per tuning frame, everything `perceive` outputs (the scene JSON with
its boxes, faces, warnings, adjustments and unexplained regions, hashes of the label images) so that
a change meant only for speed can be shown to change nothing (`--compare A B`: byte-equal, else
every number within 1e-9, else the frames that differ). On held-out frames it keeps only a hash of
each frame's outputs: `--compare` then says equal or different, and nothing else is read.
`--rows OUT.jsonl` keeps the per-frame rows.
"""
from __future__ import annotations

import argparse
import hashlib
import importlib
import json
import os
import resource
import subprocess
import sys
import threading
import time
import warnings
from pathlib import Path
from typing import Any, Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from benchmarks.judge_rows import UsageError  # noqa: E402
from benchmarks.judge_summary import percentile  # noqa: E402

HELD_OUT = ("printed", "stereo")      # docs/perception.md, "Roles": timed only, never tuned on
TUNE_LOOKS = ("flat", "labels")       # the tuning looks (`labels`: printed cartons, added by h19)
TUNE_SEEDS = range(31000, 31060)
FRAME_SEED = 0
TARGET_S = 0.5

# (stage, module, attribute): the functions timed in --mode inproc; a stage's time excludes the
# tapped stages it calls. Class methods are named "Class.method".
STAGES = (
    ("forward", "shelfpick.perception.onnx_net", "OnnxNet.__call__"),
    ("seg_post", "shelfpick.perception.segment_learned", "LearnedSegmenter.segment"),
    ("depth_rules", "shelfpick.perception.segment_depth", "DepthEdgeSegmenter.segment"),
    ("face_gate", "shelfpick.perception.segment_learned", "keep_faces"),
    ("face_gate", "shelfpick.perception.segment_learned", "plausible_faces"),
    ("refine", "shelfpick.perception.pipeline", "refine"),
    ("grow_on_plane", "shelfpick.perception.pipeline", "grow_on_plane"),
    ("catalogue", "shelfpick.perception.pipeline", "apply_catalogue"),
    ("measure_faces", "shelfpick.perception.pipeline", "measure_front"),
    ("boxes", "shelfpick.perception.pipeline", "boxes_from_masks"),
    ("make_valid", "shelfpick.perception.pipeline", "make_valid"),
    ("unexplained", "shelfpick.perception.pipeline", "candidates"),
    ("unexplained", "shelfpick.perception.pipeline", "find_unexplained"),
    ("overlay", "shelfpick.perception.pipeline", "draw_overlay"),
    ("overlay", "shelfpick.perception.pipeline", "draw_unexplained"),
)
STAGE_NAMES = tuple(dict.fromkeys(s for s, _, _ in STAGES)) + ("other", "perceive", "writing", "frame")


# --------------------------------------------------------------------------
# another version of perception, for the "before" of a change
def use_perception_from(folder: str) -> None:
    """Import `shelfpick.perception` from `folder` (a perception/ tree, e.g. `git archive COMMIT
    perception | tar -x -C DIR` then DIR/perception, with DIR/static linked to the repo's static/)
    instead of the working tree's; before anything imports it."""
    import importlib.util

    import shelfpick

    if "shelfpick.perception" in sys.modules:
        raise SystemExit("perceive_speed: --perception-from: shelfpick.perception is imported already")
    init = Path(folder) / "__init__.py"
    if not init.is_file():
        raise SystemExit(f"perceive_speed: --perception-from: {folder} has no __init__.py (a perception/ folder)")
    spec = importlib.util.spec_from_file_location("shelfpick.perception", init, submodule_search_locations=[folder])
    mod = importlib.util.module_from_spec(spec)
    sys.modules["shelfpick.perception"] = mod
    spec.loader.exec_module(mod)   # type: ignore[union-attr]
    assert shelfpick is not None


# --------------------------------------------------------------------------
# frames
def load_avg() -> str:
    """`uptime`'s load averages (1, 5, 15 min)."""
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def shelf_names(which: str, judge_dir: Path, shelves: str) -> list:
    """The shelves `--shelves` names: tuning seeds (a range A-B or a comma list) or the judge's
    shelves (`camera_to_plan.judge_shelves`); ValueError or UsageError naming the value otherwise."""
    if which == "tune":
        from benchmarks.perceive_generated import tuning_seeds

        return list(TUNE_SEEDS) if shelves == "all" else tuning_seeds(shelves, "--shelves")
    from benchmarks.camera_to_plan import judge_shelves

    return judge_shelves(judge_dir, shelves)


def frame_list(which: str, judge_dir: Path, names: list, tune_look: str = "flat") -> list[tuple[str, str, dict]]:
    """(look, shelf name, true scene dict) of every frame of the set, on the shelves `names`
    (`shelf_names`; `tune_look`: the tuning look, `flat` or `labels`, docs/perception.md "Roles")."""
    if which == "tune":
        from benchmarks.perceive_generated import tune_scene

        cache = Path(os.environ.get("TMPDIR", "/tmp")) / "perceive_speed_shelves"
        return [(tune_look, str(n), tune_scene(n, cache)) for n in names]
    scenes = judge_dir / "scenes"
    docs = {n: json.loads((scenes / f"{n}.json").read_text(encoding="utf-8")) for n in names}
    return [(look, n, docs[n]) for look in HELD_OUT for n in names]


def frame_folder(frames: Path, look: str, name: str, truth: dict) -> Path:
    """The capture folder of a frame, written by the generator unless it is there already."""
    from benchmarks.generators import write_frame

    folder = frames / look / name
    meta = folder / "meta.json"
    if not meta.exists() or json.loads(meta.read_text()).get("seed") != FRAME_SEED:
        scene_name = f"tune{name}" if look in TUNE_LOOKS else name   # as perceive_generated / camera_to_plan name them
        write_frame(truth, look, FRAME_SEED, folder, scene_name)
    return folder


def inputs(folder: Path) -> dict[str, Path]:
    return {"rgb": folder / "rgb.png", "depth": folder / "depth.png", "camera": folder / "camera.json"}


# --------------------------------------------------------------------------
# stage timing in process
class Taps:
    """Wraps the functions of `STAGES` to add up wall and CPU time per stage, each exclusive of the
    tapped stages it calls (a stack of open calls per thread; CPU is the calling thread's). A stage
    run on another thread (the depth rules, beside the network's pass) overlaps the main thread's
    stages: its time is also added to `beside`, and `other` leaves it out."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}
        self.beside: dict[str, float] = {}        # stage -> wall seconds on other threads
        self.local = threading.local()            # .stack: per open call [child wall, child cpu]
        self.undo: list[Callable[[], None]] = []
        self.lock = threading.Lock()
        for stage, mod, attr in STAGES:
            self._wrap(stage, importlib.import_module(mod), attr)

    def _wrap(self, stage: str, module: Any, attr: str) -> None:
        owner, name = module, attr
        if "." in attr:
            cls, name = attr.split(".")
            owner = getattr(module, cls)
        inner = owner.__dict__[name] if isinstance(owner, type) else getattr(owner, name)
        taps = self

        def tapped(*a, **k):
            stack = taps.local.__dict__.setdefault("stack", [])
            stack.append([0.0, 0.0])
            w, c = time.perf_counter(), time.thread_time()
            try:
                return inner(*a, **k)
            finally:
                dw, dc = time.perf_counter() - w, time.thread_time() - c
                kw, kc = stack.pop()
                with taps.lock:
                    taps.wall[stage] = taps.wall.get(stage, 0.0) + dw - kw
                    taps.cpu[stage] = taps.cpu.get(stage, 0.0) + dc - kc
                    if not stack and threading.current_thread() is not threading.main_thread():
                        taps.beside[stage] = taps.beside.get(stage, 0.0) + dw - kw
                if stack:
                    stack[-1][0] += dw
                    stack[-1][1] += dc

        setattr(owner, name, tapped)
        self.undo.append(lambda: setattr(owner, name, inner))

    def reset(self) -> None:
        self.wall, self.cpu, self.beside = {}, {}, {}

    def close(self) -> None:
        for u in reversed(self.undo):
            u()


def write_outputs(result: Any, out: Path) -> None:
    """What `shelfpick perceive --out --overlay --masks --report` writes (perception/cmd_perceive.py)."""
    import cv2

    from shelfpick.perception.scene import write_json

    result.scene.save(out / "perceived.json")
    cv2.imwrite(str(out / "overlay.png"), cv2.cvtColor(result.overlay, cv2.COLOR_RGB2BGR))
    cv2.imwrite(str(out / "perceived_masks.png"), result.masks)
    write_json(out / "report.json", result.summary())


def inproc_frame(folder: Path, seg: Any, taps: Taps, out: Path) -> tuple[dict, Any]:
    """One frame perceived in this process: (row of per-stage wall/CPU seconds, the Perception)."""
    from shelfpick.perception.capture import load_capture
    from shelfpick.perception.pipeline import perceive

    cap = load_capture(**inputs(folder))
    taps.reset()
    w, c = time.perf_counter(), time.process_time()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        res = perceive(cap, seg)
    pw, pc = time.perf_counter() - w, time.process_time() - c
    out.mkdir(parents=True, exist_ok=True)
    write_outputs(res, out)
    fw, fc = time.perf_counter() - w, time.process_time() - c
    wall, cpu = dict(taps.wall), dict(taps.cpu)
    # other: perceive's time outside the tapped stages, on the main thread (CPU: the process's,
    # less every stage's, so a stage on another thread is not counted twice)
    wall["other"] = pw - (sum(wall.values()) - sum(taps.beside.values()))
    cpu["other"] = pc - sum(cpu.values())
    wall.update(perceive=pw, writing=fw - pw, frame=fw)
    cpu.update(perceive=pc, writing=fc - pc, frame=fc)
    return {"wall": wall, "cpu": cpu, "boxes": len(res.scene.boxes)}, res


def run_inproc(frames: list[tuple[str, str, Path]], out: Path) -> list[dict]:
    """Every frame in this process after one warm-up frame (not counted)."""
    from shelfpick.perception.segment import load_segmenter

    from shelfpick.perception.heap_pages import keep_freed_pages

    keep_freed_pages()        # as the console does at its start
    w, c = time.perf_counter(), time.process_time()
    seg = load_segmenter(None, "auto")
    seg.choose(True)          # the learned network loaded once, as the console holds it
    print(f"segmenter loaded in {time.perf_counter() - w:.2f} s wall, {time.process_time() - c:.2f} s CPU",
          file=sys.stderr)
    taps = Taps()
    rows = []
    try:
        inproc_frame(frames[0][2], seg, taps, out / "warmup")
        for i, (look, name, folder) in enumerate(frames):
            row, _ = inproc_frame(folder, seg, taps, out / look / name)
            rows.append(dict(row, look=look, shelf=name) if look not in HELD_OUT else
                        {k: v for k, v in dict(row, look=look, shelf=name).items() if k != "boxes"})
            said = f", {row['boxes']} boxes" if look not in HELD_OUT else ""    # held out: time only
            print(f"[{i + 1}/{len(frames)}] {look} {name}: {row['wall']['perceive']:.2f} s wall, "
                  f"{row['cpu']['perceive']:.2f} s CPU perceive{said} (load {load_avg()})",
                  file=sys.stderr, flush=True)
    finally:
        taps.close()
    return rows


# --------------------------------------------------------------------------
# before and after, frame by frame (--ab-with)
def worker(out: Path) -> int:
    """`--worker OUT`: perceive each capture folder named on stdin (a JSON line: folder, look, shelf)
    in this process, the segmenter loaded once, and answer each with its row (a JSON line)."""
    from shelfpick.perception.segment import load_segmenter

    answer, sys.stdout = sys.stdout, sys.stderr          # only the rows go to the parent
    seg = load_segmenter(None, "auto")
    seg.choose(True)
    taps = Taps()
    for line in sys.stdin:
        req = json.loads(line)
        row, _ = inproc_frame(Path(req["folder"]), seg, taps, out / req["look"] / req["shelf"])
        answer.write(json.dumps(row) + "\n")
        answer.flush()
    taps.close()
    return 0


def run_ab(frames: list[tuple[str, str, Path]], out: Path, before: str) -> dict[str, list[dict]]:
    """Every frame perceived by two warm processes in turn, perception from `before` and the working
    tree's, never both at once, which goes first alternating frame by frame: on a shared machine
    both see the same load, minute by minute (two whole runs one after the other do not)."""
    me = [sys.executable, str(Path(__file__).resolve()), "--worker"]
    procs = {"before": subprocess.Popen(me + [str(out / "before"), "--perception-from", before],
                                        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True),
             "after": subprocess.Popen(me + [str(out / "after")], stdin=subprocess.PIPE,
                                       stdout=subprocess.PIPE, text=True)}

    def ask(side: str, look: str, name: str, folder: Path) -> dict:
        p = procs[side]
        p.stdin.write(json.dumps({"folder": str(folder), "look": look, "shelf": name}) + "\n")  # type: ignore[union-attr]
        p.stdin.flush()                                                                      # type: ignore[union-attr]
        line = p.stdout.readline()                                                           # type: ignore[union-attr]
        if not line:
            raise SystemExit(f"perceive_speed: --ab-with: the {side} process ended (exit {p.wait()})")
        row = json.loads(line)
        return dict(row, look=look, shelf=name) if look not in HELD_OUT else \
            {k: v for k, v in dict(row, look=look, shelf=name).items() if k != "boxes"}

    rows: dict[str, list[dict]] = {"before": [], "after": []}
    try:
        for side in procs:                                   # one warm-up frame each, not counted
            ask(side, "warmup", "warmup", frames[0][2])
        for i, (look, name, folder) in enumerate(frames):
            for side in (("before", "after") if i % 2 == 0 else ("after", "before")):
                rows[side].append(ask(side, look, name, folder))
            b, a = rows["before"][-1], rows["after"][-1]
            print(f"[{i + 1}/{len(frames)}] {look} {name}: before {b['wall']['perceive']:.2f} s wall "
                  f"{b['cpu']['perceive']:.2f} s CPU, after {a['wall']['perceive']:.2f} / {a['cpu']['perceive']:.2f} "
                  f"(load {load_avg()})", file=sys.stderr, flush=True)
    finally:
        for p in procs.values():
            p.stdin.close()                                  # type: ignore[union-attr]
            p.wait(timeout=60)
    return rows


def paired(rows: dict[str, list[dict]]) -> str:
    """Per look: the median over frames of after / before, wall and CPU of `perceive`."""
    lines = ["| look | frames | after / before wall, median of frames | CPU |", "|---|---|---|---|"]
    looks = list(dict.fromkeys(r["look"] for r in rows["before"]))
    for look in looks + ["all"]:
        pairs = [(b, a) for b, a in zip(rows["before"], rows["after"]) if look in ("all", b["look"])]
        rw = [a["wall"]["perceive"] / b["wall"]["perceive"] for b, a in pairs]
        rc = [a["cpu"]["perceive"] / max(b["cpu"]["perceive"], 1e-9) for b, a in pairs]
        lines.append(f"| {look} | {len(pairs)} | {percentile(rw, 0.5):.3f} | {percentile(rc, 0.5):.3f} |")
    return "\n".join(lines)


# --------------------------------------------------------------------------
# the CLI, a process per frame
def tree_env(tree: str, pycache: str | None) -> dict[str, str]:
    """The environment in which `import shelfpick` is another commit's whole tree `tree` (`git archive
    COMMIT | tar -x -C TREE`): a folder of links named as pyproject.toml maps the packages, ahead of the
    installed (editable) one on PYTHONPATH."""
    root = Path(tree).resolve()
    pkg = root / "_as_installed" / "shelfpick"
    pkg.mkdir(parents=True, exist_ok=True)
    for name, src in (("__init__.py", "shelfpick/__init__.py"), ("perception", "perception"),
                      ("planning", "planning"), ("console", "console"), ("robotsim", "robotsim"), ("static", "static")):
        if not (pkg / name).exists():
            (pkg / name).symlink_to(root / src)
    env = dict(child_env(pycache) or os.environ)
    env["PYTHONPATH"] = str(pkg.parent)
    env["PYTHONSAFEPATH"] = "1"        # nor the working directory (a checkout's shelfpick/) ahead of it
    return env


def child_env(pycache: str | None) -> dict[str, str] | None:
    """The environment of a timed process: as this one's, or with `pycache` (`--pycache DIR`) its
    bytecode cached in DIR, outside the repo (PYTHONPYCACHEPREFIX), even where
    PYTHONDONTWRITEBYTECODE is set: an installed package's modules are compiled once, at install,
    but a process that may not write bytecode compiles the repo's own modules from source every
    time (~0.1 s a process here)."""
    if pycache is None:
        return None
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    env["PYTHONPYCACHEPREFIX"] = str(Path(pycache).resolve())
    return env


def run_cli(frames: list[tuple[str, str, Path]], out: Path, given: str | None = None,
            perception_from: str | None = None, pycache: str | None = None, env: dict[str, str] | None = None,
            cmd: list[str] | None = None) -> list[dict]:
    """`shelfpick perceive` on each frame, one process each: wall, the child's CPU, perceive's own total.
    `given`: the command to run instead of `shelfpick` beside this Python (split at spaces); `env`,
    `cmd`: the process's environment (else `child_env(pycache)`) and command (else as `given` says)."""
    exe = Path(sys.executable).with_name("shelfpick")
    cmd = cmd or (given.split() if given else [str(exe)] if exe.exists() else ["shelfpick"])
    env = env if env is not None else child_env(pycache)
    if perception_from:          # `shelfpick` run by this script with that perception imported
        cmd = [sys.executable, str(Path(__file__).resolve()), "--perception-from", perception_from, "--as-cli"]
    rows = []
    for i, (look, name, folder) in enumerate(frames[:1] * bool(pycache) + frames):   # --pycache: one untimed first
        d = out / look / name
        d.mkdir(parents=True, exist_ok=True)
        src = inputs(folder)
        argv = cmd + ["perceive", "--rgb", str(src["rgb"]), "--depth", str(src["depth"]), "--camera",
                      str(src["camera"]), "--out", str(d / "perceived.json"), "--report", str(d / "report.json"),
                      "--masks", str(d / "perceived_masks.png"), "--overlay", str(d / "overlay.png")]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w = time.perf_counter()
        p = subprocess.run(argv, capture_output=True, text=True, timeout=600, env=env)
        wall = time.perf_counter() - w
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        if p.returncode != 0:       # the exit status only: a held-out frame's output is not read
            raise SystemExit(f"perceive_speed: {look} {name}: shelfpick perceive exit {p.returncode}")
        total = json.loads((d / "report.json").read_text())["timing"]["total"]
        if pycache and i == 0:
            continue                # the run that filled the bytecode cache
        rows.append({"look": look, "shelf": name, "wall": {"frame": wall, "perceive": total},
                     "cpu": {"frame": cpu}})
        print(f"[{i + 1 - bool(pycache)}/{len(frames)}] {look} {name}: {wall:.2f} s wall ({total:.2f} s in perceive), "
              f"{cpu:.2f} s CPU (load {load_avg()})", file=sys.stderr, flush=True)
    return rows


# --------------------------------------------------------------------------
# one process's phases (--mode split)
SPLIT = ("interpreter", "cli_import", "perceive_imports", "read", "seg_import", "session", "forward_first",
         "perceive_rest", "write", "exit", "process", "forward_again")


def run_split(frames: list[tuple[str, str, Path]], out: Path, pycache: str | None = None,
              env: dict[str, str] | None = None) -> list[dict]:
    """`benchmarks/perceive_startup.py` on each frame, a fresh process each: the phases of one
    `shelfpick perceive` process (that script's docstring), the interpreter's start (spawn to its
    first line) and exit (its last stamp to the parent seeing it end) from the parent's clock."""
    child = Path(__file__).resolve().with_name("perceive_startup.py")
    env = env if env is not None else child_env(pycache)
    rows = []
    for i, (look, name, folder) in enumerate(frames[:1] * bool(pycache) + frames):   # --pycache: one untimed first
        d = out / look / name
        d.mkdir(parents=True, exist_ok=True)
        t = time.time()
        p = subprocess.run([sys.executable, str(child), str(folder), str(d)], capture_output=True, text=True,
                           timeout=600, env=env)
        end = time.time()
        if p.returncode != 0:       # the exit status only: a held-out frame's output is not read
            raise SystemExit(f"perceive_speed: {look} {name}: perceive_startup.py exit {p.returncode}")
        r = json.loads(p.stdout.strip().splitlines()[-1])
        if pycache and i == 0:
            continue                # the run that filled the bytecode cache
        wall = {k: r[k] for k in SPLIT if k in r}
        wall.update(interpreter=r["start"] - t, exit=end - r["end"], perceive_rest=r["perceive"] - r["forward_first"])
        wall["process"] = wall["interpreter"] + r["total"] + wall["exit"]     # less the extra passes
        rows.append({"look": look, "shelf": name, "wall": wall})
        print(f"[{i + 1 - bool(pycache)}/{len(frames)}] {look} {name}: {wall['process']:.2f} s process, "
              + ", ".join(f"{k} {wall[k]:.3f}" for k in SPLIT[:-2]) + f" (load {load_avg()})",
              file=sys.stderr, flush=True)
    return rows


def split_summary(rows: list[dict]) -> str:
    """p50, p90 and mean wall per phase of the process, all frames."""
    lines = ["| phase | wall p50 | wall p90 | wall mean |", "|---|---|---|---|"]
    for k in SPLIT:
        v = [r["wall"][k] for r in rows]
        lines.append(f"| {k} | {percentile(v, 0.5):.3f} | {percentile(v, 0.9):.3f} | {np.mean(v):.3f} |")
    return "\n".join(lines) + ("\n\n(`process`: spawn to exit, the phases above it add up to it; "
                               "`forward_again`: a second pass of the same input, outside the process's work.)")


def run_process_ab(frames: list[tuple[str, str, Path]], out: Path, mode: str, tree: str | None,
                   pycache: str | None) -> dict[str, list[dict]]:
    """`--mode cli|split --ab-tree TREE`: each frame run by a process of TREE's code (before) and one of
    the working tree's (after), one after the other, which goes first alternating frame by frame, so
    that both meet the same load. `tree` None (`--ab-pycache`): the working tree's both, before under
    PYTHONDONTWRITEBYTECODE (a checkout without __pycache__ then compiles its modules every time), after
    with its bytecode cached in `pycache`."""
    cmd = {"before": [sys.executable, "-m", "shelfpick.console.cli"] if tree else None, "after": None}
    plain = {k: v for k, v in os.environ.items() if k != "PYTHONPYCACHEPREFIX"}
    env = {"before": tree_env(tree, pycache) if tree else dict(plain, PYTHONDONTWRITEBYTECODE="1"),
           "after": child_env(pycache)}
    rows: dict[str, list[dict]] = {"before": [], "after": []}
    for i, frame in enumerate(frames[:1] * bool(pycache) + frames):      # --pycache: one untimed pair first
        for side in (("before", "after") if i % 2 == 0 else ("after", "before")):
            one = (run_cli([frame], out / side, env=env[side], cmd=cmd[side]) if mode == "cli"
                   else run_split([frame], out / side, env=env[side]))
            if not (pycache and i == 0):
                rows[side] += one
        if not (pycache and i == 0):
            k = "process" if mode == "split" else "frame"
            print(f"  before {rows['before'][-1]['wall'][k]:.2f} s, after {rows['after'][-1]['wall'][k]:.2f} s",
                  file=sys.stderr, flush=True)
    return rows


def outputs_digest(folder: Path) -> str:
    """One hash of what `shelfpick perceive` wrote in `folder` (the scene, masks, overlay, and the report
    less its timing): two processes' outputs are equal or not, nothing more is read of them."""
    d = hashlib.sha256()
    for name in ("perceived.json", "perceived_masks.png", "overlay.png"):
        d.update((folder / name).read_bytes())
    report = json.loads((folder / "report.json").read_text())
    report.pop("timing", None)
    d.update(json.dumps(report, sort_keys=True).encode())
    return d.hexdigest()


def compare_outputs(a: Path, b: Path) -> tuple[int, list[str]]:
    """(frames whose outputs are equal, frames that differ or are missing on one side) of two `--out`
    folders of `--mode cli` (LOOK/SHELF/ each)."""
    names = sorted({str(p.parent.relative_to(root)) for root in (a, b) for p in root.glob("*/*/report.json")})
    same, diff = 0, []
    for n in names:
        try:
            equal = outputs_digest(a / n) == outputs_digest(b / n)
        except (OSError, ValueError):
            equal = False
        same, diff = (same + 1, diff) if equal else (same, diff + [n])
    return same, diff


def paired_process(rows: dict[str, list[dict]], key: str) -> str:
    """Per look: the median over frames of after / before of a process's wall time."""
    lines = ["| look | frames | after / before wall, median of frames |", "|---|---|---|"]
    for look in list(dict.fromkeys(r["look"] for r in rows["before"])) + ["all"]:
        rw = [a["wall"][key] / b["wall"][key] for b, a in zip(rows["before"], rows["after"]) if look in ("all", b["look"])]
        lines.append(f"| {look} | {len(rw)} | {percentile(rw, 0.5):.3f} |")
    return "\n".join(lines)


# --------------------------------------------------------------------------
# figures
def summary(rows: list[dict], mode: str) -> str:
    """A markdown table per look: p50/p90 of the frame; for inproc, p50 and mean per stage."""
    lines = []
    looks = list(dict.fromkeys(r["look"] for r in rows))
    key = "perceive" if mode == "inproc" else "frame"
    lines.append(f"| look | frames | wall p50 | wall p90 | CPU p50 | CPU p90 | frames <= {TARGET_S} s wall |")
    lines.append("|---|---|---|---|---|---|---|")
    for look in looks + ["all"]:
        rs = [r for r in rows if look in ("all", r["look"])]
        wl = [r["wall"][key] for r in rs]
        cp = [r["cpu"][key] for r in rs]
        lines.append(f"| {look} | {len(rs)} | {percentile(wl, 0.5):.3f} | {percentile(wl, 0.9):.3f} | {percentile(cp, 0.5):.3f} | "
                     f"{percentile(cp, 0.9):.3f} | {sum(v <= TARGET_S for v in wl)} |")
    if mode == "cli":
        pw = [r["wall"]["perceive"] for r in rows]
        lines.append(f"\n(`{key}` is the process's whole run; of it, `perceive` itself: wall p50 "
                     f"{percentile(pw, 0.5):.3f}, p90 {percentile(pw, 0.9):.3f} s.)")
        return "\n".join(lines)
    lines.append("\nStages (seconds a frame, all looks; each exclusive of the stages it calls):\n")
    lines.append("| stage | wall p50 | wall mean | CPU p50 | CPU mean | CPU share of perceive |")
    lines.append("|---|---|---|---|---|---|")
    total_cpu = sum(r["cpu"]["perceive"] for r in rows)
    for s in STAGE_NAMES:
        wl = [r["wall"].get(s, 0.0) for r in rows]
        cp = [r["cpu"].get(s, 0.0) for r in rows]
        share = "" if s in ("perceive", "writing", "frame") else f"{100 * sum(cp) / total_cpu:.0f}%"
        lines.append(f"| {s} | {percentile(wl, 0.5):.3f} | {np.mean(wl):.3f} | {percentile(cp, 0.5):.3f} | {np.mean(cp):.3f} | {share} |")
    return "\n".join(lines)


# --------------------------------------------------------------------------
# fingerprint: outputs unchanged by a speed-up
def _h(a: np.ndarray | None) -> str:
    if a is None:
        return "none"
    a = np.ascontiguousarray(a)
    return hashlib.sha256(str(a.shape).encode() + str(a.dtype).encode() + a.tobytes()).hexdigest()[:16]


def fingerprint(frames: list[tuple[str, str, Path]]) -> dict:
    """Per frame: the scene JSON, faces, warnings, adjustments and hashes of the label images; of a
    held-out frame only a hash of all that (equal or not is all a speed change may ask of it)."""
    from shelfpick.perception.capture import load_capture
    from shelfpick.perception.pipeline import perceive
    from shelfpick.perception.segment import load_segmenter

    seg = load_segmenter(None, "auto")
    out = {}
    for i, (look, name, folder) in enumerate(frames):
        cap = load_capture(**inputs(folder))
        t = time.process_time()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            res = perceive(cap, seg)
        cpu = time.process_time() - t
        doc = {"scene": res.scene.to_json(), "faces": [f.to_json() for f in res.faces],
               "warnings": list(res.warnings), "adjustments": list(res.adjustments),
               "masks": _h(res.masks), "unexplained_labels": _h(res.unexplained_labels), "overlay": _h(res.overlay)}
        out[f"{look}/{name}"] = dict(kept(look, doc), cpu_s=cpu)
        said = "" if look in HELD_OUT else f"{len(res.scene.boxes)} boxes, "
        print(f"[{i + 1}/{len(frames)}] {look} {name}: {said}{cpu:.2f} s CPU", file=sys.stderr, flush=True)
    return out


def kept(look: str, doc: dict) -> dict:
    """What a fingerprint keeps of a frame's outputs: all of a tuning frame's; of a held-out frame
    only their hash, so that equal or not is all anyone can learn from it."""
    if look not in HELD_OUT:
        return doc
    return {"digest": hashlib.sha256(json.dumps(doc, sort_keys=True).encode()).hexdigest()}


def _close(a: Any, b: Any, tol: float) -> bool:
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_close(a[k], b[k], tol) for k in a)
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(_close(x, y, tol) for x, y in zip(a, b))
    if isinstance(a, float) and isinstance(b, (int, float)) or isinstance(b, float) and isinstance(a, (int, float)):
        return abs(a - b) <= tol
    return a == b


def compare(a: dict, b: dict, tol: float = 1e-9) -> tuple[int, list[str], list[str]]:
    """(frames byte-equal, frames equal within tol only, frames different); cpu_s is not compared."""
    same, close, diff = 0, [], []
    for k in sorted(set(a) | set(b)):
        fa = {x: v for x, v in a.get(k, {}).items() if x != "cpu_s"}
        fb = {x: v for x, v in b.get(k, {}).items() if x != "cpu_s"}
        if json.dumps(fa, sort_keys=True) == json.dumps(fb, sort_keys=True) and k in a and k in b:
            same += 1
        elif k in a and k in b and _close(fa, fb, tol):
            close.append(k)
        else:
            diff.append(k)
    return same, close, diff


# --------------------------------------------------------------------------
def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if "--worker" in argv:       # a warm process of --ab-with (the parent reads its stdout)
        if "--perception-from" in argv:
            use_perception_from(argv[argv.index("--perception-from") + 1])
        return worker(Path(argv[argv.index("--worker") + 1]))
    if "--as-cli" in argv:       # `shelfpick ARGS` with --perception-from's perception (the CLI's "before")
        k = argv.index("--as-cli")
        folder = argv[argv.index("--perception-from") + 1]
        use_perception_from(folder)
        from shelfpick.console.cli import main as cli_main

        sys.argv = ["shelfpick"] + argv[k + 1:]
        return cli_main()
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--set", choices=("held_out", "tune"), default="held_out")
    ap.add_argument("--mode", choices=("inproc", "cli", "split"), default="inproc",
                    help="split: a process per frame, timed phase by phase (benchmarks/perceive_startup.py)")
    ap.add_argument("--tune-look", choices=TUNE_LOOKS, default="flat",
                    help="--set tune: the look (labels: printed cartons under a hard light)")
    ap.add_argument("--shelves", default="all", help="all, or a comma list (judge shelves s00,u03 or tune seeds)")
    ap.add_argument("--judge-dir", default=str(ROOT.parent / "shared" / "judge"))
    ap.add_argument("--frames", default=str(Path(os.environ.get("TMPDIR", "/tmp")) / "perceive_speed_frames"),
                    help="capture folders (written once, reused)")
    ap.add_argument("--out", default=None, help="folder for the perceived outputs (default <frames>.out)")
    ap.add_argument("--rows", default=None, help="write the per-frame rows here (JSONL)")
    ap.add_argument("--shelfpick", default=None, help="--mode cli: the command to run (default: shelfpick beside this Python)")
    ap.add_argument("--ab-tree", metavar="TREE",
                    help="--mode cli/split: before and after frame by frame, a process each: TREE (a whole other "
                         "commit, `git archive COMMIT | tar -x -C TREE`) and the working tree")
    ap.add_argument("--ab-pycache", action="store_true",
                    help="--mode cli/split with --pycache: the working tree's processes without (before) and with "
                         "(after) the bytecode cache, frame by frame")
    ap.add_argument("--pycache", metavar="DIR",
                    help="--mode cli/split: the processes' bytecode cached in DIR (outside the repo), as an "
                         "installed package's is, even under PYTHONDONTWRITEBYTECODE")
    ap.add_argument("--fingerprint", metavar="OUT", help="write the outputs' fingerprint of the frames (JSON)")
    ap.add_argument("--compare", nargs=2, metavar=("A", "B"), help="compare two fingerprints")
    ap.add_argument("--compare-outputs", nargs=2, metavar=("A", "B"),
                    help="compare two --mode cli --out folders (e.g. OUT/before and OUT/after of --ab-tree): "
                         "frames whose written outputs are equal (report less its timing)")
    ap.add_argument("--perception-from", metavar="DIR",
                    help="time shelfpick.perception from DIR (a perception/ folder of another commit) instead of the tree's")
    ap.add_argument("--ab-with", metavar="DIR",
                    help="in process, before and after frame by frame: perception from DIR (as --perception-from) "
                         "and the working tree's, in two warm processes taking turns")
    ap.add_argument("--blas-threads-as-is", action="store_true",
                    help="in process: perceive without its one-BLAS-thread limit (to time that change alone)")
    ap.add_argument("--profile", metavar="OUT", help="--mode inproc under cProfile (stats to OUT; --set tune only)")
    a = ap.parse_args(argv)
    if a.compare_outputs:
        same, diff = compare_outputs(*(Path(p) for p in a.compare_outputs))
        print(f"{same} frames' outputs equal, {len(diff)} different {diff}")
        return 1 if diff else 0
    if a.compare:
        fa, fb = (json.loads(Path(p).read_text()) for p in a.compare)
        same, close, diff = compare(fa, fb)
        print(f"{same} frames byte-equal, {len(close)} equal within 1e-9 {close}, {len(diff)} different {diff}")
        ca, cb = ([v["cpu_s"] for v in f.values()] for f in (fa, fb))
        print(f"perceive CPU p50 {percentile(ca, 0.5):.3f} -> {percentile(cb, 0.5):.3f} s")
        return 1 if diff else 0
    if a.set == "held_out" and not (Path(a.judge_dir) / "scenes").is_dir():
        print(f"perceive_speed: --judge-dir: {a.judge_dir} has no scenes/ (the judge's shelves)", file=sys.stderr)
        return 2
    if a.set == "held_out" and a.profile:
        print("perceive_speed: --profile: only on --set tune (a profile chooses what to change)", file=sys.stderr)
        return 2
    if a.perception_from:
        use_perception_from(a.perception_from)
    if a.blas_threads_as_is:
        import contextlib

        import shelfpick.perception.pipeline as pipeline

        pipeline.one_blas_thread = contextlib.nullcontext   # type: ignore[attr-defined]
    try:
        names = shelf_names(a.set, Path(a.judge_dir), a.shelves)
    except (ValueError, UsageError) as exc:
        print(f"perceive_speed: {exc}", file=sys.stderr)
        return 2
    frames_dir = Path(a.frames)
    t = time.perf_counter()
    frames = [(look, n, frame_folder(frames_dir, look, n, truth))
              for look, n, truth in frame_list(a.set, Path(a.judge_dir), names, a.tune_look)]
    print(f"{len(frames)} frames ready in {time.perf_counter() - t:.1f} s (not counted)", file=sys.stderr)
    if a.profile:
        import cProfile
        import pstats

        prof = cProfile.Profile()
        prof.runcall(run_inproc, frames, Path(a.out) if a.out else frames_dir.with_suffix(".out"))
        prof.dump_stats(a.profile)
        pstats.Stats(a.profile).sort_stats("tottime").print_stats(40)
        return 0
    if a.fingerprint:
        doc = fingerprint(frames)
        Path(a.fingerprint).write_text(json.dumps(doc, sort_keys=True))
        print(f"fingerprint of {len(doc)} frames -> {a.fingerprint}")
        return 0
    out = Path(a.out) if a.out else frames_dir.with_suffix(".out")
    start = load_avg()
    if a.ab_with:
        both = run_ab(frames, out, a.ab_with)
        if a.rows:
            Path(a.rows).write_text("".join(json.dumps(dict(r, side=side)) + "\n" for side, rs in both.items() for r in rs))
        print(f"perceive speed, --set {a.set} --mode inproc, before ({a.ab_with}) and after (the working tree) "
              f"frame by frame, {len(frames)} frames 640x480; load (1/5/15 min) {start} at the start, "
              f"{load_avg()} at the end; {os.cpu_count()} cores")
        for side, rs in both.items():
            print(f"\n### {side}\n\n{summary(rs, 'inproc')}")
        print(f"\n### after / before, frame by frame\n\n{paired(both)}")
        return 0
    if a.ab_pycache and not a.pycache:
        print("perceive_speed: --ab-pycache needs --pycache DIR", file=sys.stderr)
        return 2
    if (a.ab_tree or a.ab_pycache) and a.mode in ("cli", "split"):
        both = run_process_ab(frames, out, a.mode, None if a.ab_pycache else a.ab_tree, a.pycache)
        if a.mode == "cli":
            same, diff = compare_outputs(out / "before", out / "after")
            print(f"outputs: {same} frames equal before and after, {len(diff)} different {diff}", file=sys.stderr)
        if a.rows:
            Path(a.rows).write_text("".join(json.dumps(dict(r, side=side)) + "\n" for side, rs in both.items() for r in rs))
        what = ("before without and after with the bytecode cache" if a.ab_pycache else
                f"before ({a.ab_tree}) and after (the working tree)")
        print(f"perceive speed, --set {a.set} --mode {a.mode}{' --pycache' if a.pycache else ''}, {what} frame by frame, a process each, {len(frames)} frames 640x480; load "
              f"(1/5/15 min) {start} at the start, {load_avg()} at the end; {os.cpu_count()} cores")
        for side, rs in both.items():
            print(f"\n### {side}\n\n{split_summary(rs) if a.mode == 'split' else summary(rs, 'cli')}")
        print(f"\n### after / before, frame by frame\n\n{paired_process(both, 'process' if a.mode == 'split' else 'frame')}")
        return 0
    if a.mode == "split":
        if a.perception_from:
            print("perceive_speed: --mode split times the working tree's perception only", file=sys.stderr)
            return 2
        rows = run_split(frames, out, a.pycache)
        if a.rows:
            Path(a.rows).write_text("".join(json.dumps(r) + "\n" for r in rows))
        print(f"perceive speed, --set {a.set} --mode split{' --pycache' if a.pycache else ''}, {len(rows)} frames "
              "640x480, a process each; "
              f"load (1/5/15 min) {start} at the start, {load_avg()} at the end; {os.cpu_count()} cores")
        print(split_summary(rows))
        return 0
    rows = run_inproc(frames, out) if a.mode == "inproc" else run_cli(frames, out, a.shelfpick, a.perception_from,
                                                                      a.pycache)
    if a.rows:
        Path(a.rows).write_text("".join(json.dumps(r) + "\n" for r in rows))
    print(f"perceive speed, --set {a.set} --mode {a.mode}{' --pycache' if a.pycache else ''}, {len(rows)} frames 640x480; "
          f"load (1/5/15 min) {start} at the start, {load_avg()} at the end; {os.cpu_count()} cores")
    print(summary(rows, a.mode))
    return 0


if __name__ == "__main__":
    sys.exit(main())
