"""Predictions under depth uncertainty: one settled world per depth sample.

A camera sees front faces only, so a perceived box's depth is unknown. The
method draws N depths per unknown box (front face kept, never past the back
wall) and judges every removal in all N worlds; a prediction is the
aggregate. Each world is built and settled once; the state after taking a
set of boxes away is cached with saveState, and every trial starts from a
restoreState, so a trial costs one pull, not a rebuild.
"""
from __future__ import annotations

import random
import time
import warnings
import zlib
from collections import Counter
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

from perception.errors import SceneError
from perception.scene import Box, Scene, quat_to_matrix
from planning.physics import PhysicsConfig
from planning.plan import StepPrediction
from planning.sim import ShelfSim, StepResult
from planning.uncertainty import Uncertainty, draw_config, draw_scene


def depth_range(scene: Scene, box: Box, config: PhysicsConfig | None = None) -> tuple[float, float]:
    """(lowest, highest) depth a box with unknown depth may have.

    The highest keeps every back corner in front of the back wall and in front
    of any box whose front face lies behind this one's (a hidden box cannot
    pass through a visible one). The lowest is `min_sample_depth` (0.15 m, the
    shallowest of the method's box types is 0.17 m), never above the highest.
    """
    cfg = config or PhysicsConfig()
    r = quat_to_matrix(box.orientation)
    face = _face(box)
    face_max_y = max(c[1] for c in face)
    dy = r[1][1]  # how much of the box's depth axis points into the shelf
    if dy < 0.2:
        return (box.size[1], box.size[1])  # lying sideways: the depth is not along y; keep it
    hi = (scene.shelf.depth - face_max_y) / dy
    x0, x1 = min(c[0] for c in face), max(c[0] for c in face)
    z0, z1 = min(c[2] for c in face), max(c[2] for c in face)
    for other in scene.boxes:
        if other.id == box.id:
            continue
        cs = other.corners() if other.depth_known else _face(other)
        ox0, ox1 = min(c[0] for c in cs), max(c[0] for c in cs)
        oz0, oz1 = min(c[2] for c in cs), max(c[2] for c in cs)
        oy0 = min(c[1] for c in cs)
        # only a face really behind this one bounds it: a neighbour in the same column
        # overlaps by a few mm through tilt or noise, and bounding by it gave 1 cm deep boxes
        ov = _OCCLUSION_OVERLAP
        if ox0 < x1 - ov and x0 + ov < ox1 and oz0 < z1 - ov and z0 + ov < oz1 and oy0 > face_max_y - 0.005:
            bound = (oy0 - face_max_y) / dy
            if bound >= cfg.min_sample_depth:
                hi = min(hi, bound)
    hi = max(hi, 0.01)
    lo = min(cfg.min_sample_depth, hi)
    return (lo, hi)


_OCCLUSION_OVERLAP = 0.05  # m of face overlap in x and in z before a face counts as behind another


def _face(b: Box) -> list:
    r = quat_to_matrix(b.orientation)
    f = b.front_center
    hx, hz = b.size[0] / 2, b.size[2] / 2
    return [tuple(f[i] + sx * r[i][0] * hx + sz * r[i][2] * hz for i in range(3))
            for sx in (-1, 1) for sz in (-1, 1)]


def depth_ranges(scene: Scene, config: PhysicsConfig | None = None) -> dict[str, tuple[float, float]]:
    """`depth_range` of every box with an unknown depth (the same for every sample: compute once)."""
    return {b.id: depth_range(scene, b, config) for b in scene.boxes if not b.depth_known}


def sample_depths(scene: Scene, seed: int, sample: int, config: PhysicsConfig | None = None,
                  reach: float = 1.0, ranges: dict[str, tuple[float, float]] | None = None) -> Scene:
    """One depth sample of the scene: unknown depths drawn uniformly in `depth_range`.

    Ranges are computed on the scene as perceived (placeholder depths for the
    others are not used as obstacles: only front faces and known boxes are).
    `reach` < 1 shrinks each range towards its lowest depth (used to redraw a
    sample whose boxes, turned in the plane, swing into a neighbour).
    `ranges` (from `depth_ranges(scene, config)`) saves recomputing them per sample.
    """
    rng = random.Random(f"shelfpick-depth:{int(seed)}:{int(sample)}")
    out = []
    for b in scene.boxes:
        if b.depth_known:
            out.append(b)
            continue
        lo, hi = ranges[b.id] if ranges is not None else depth_range(scene, b, config)
        d = rng.uniform(lo, lo + (hi - lo) * reach)
        out.append(b.with_depth(d))
    return scene.with_boxes(out)


def _stable_seed(*parts: object) -> int:
    return zlib.crc32(":".join(str(p) for p in parts).encode())


def trial_seed(seed: int, sample: int, removed: frozenset[str], box: str) -> int:
    """The vibration seed of one pull: a pure function of what is pulled where."""
    return _stable_seed(seed, sample, ",".join(sorted(removed)), box)


@dataclass(frozen=True)
class Draw:
    """One sample world as built: the world, and what the draws before it contradicted."""

    sim: ShelfSim
    rejected: tuple[Mapping[str, str], ...] = ()   # per redrawn attempt: box -> what it did
    stands: bool = True                           # False: no attempt stood as observed
    off: Mapping[str, str] = field(default_factory=dict)  # what the returned world contradicts

    @property
    def repairs(self) -> tuple[str, ...]:
        return self.sim.repairs


def contradictions(sim: ShelfSim, config: PhysicsConfig, knock: bool = True) -> dict[str, str]:
    """Boxes of a freshly settled world that did not stand as they were given, with what they did.

    Standing still is not enough: a box balanced on an edge stays put in a solver
    that nothing disturbs, so the settled world also takes a small knock
    (`ShelfSim.nudge`), and a box that then falls did not stand either (only a
    world that settled is knocked: the knock costs a settle).
    """
    out = {}
    for bid, (d, a) in sim.settle_moves.items():
        pos = sim.scene.box(bid).position
        if pos[2] < 0 or pos[1] < -0.3:
            out[bid] = f"falls off the shelf while settling (moved {d:.2f} m)"
        elif d > config.stand_tolerance:
            out[bid] = f"moves {d:.3f} m while settling (more than {config.stand_tolerance:.2f} m)"
        elif a > config.stand_rotation:
            out[bid] = f"turns {a:.0f} deg while settling (more than {config.stand_rotation:.0f} deg)"
    if out or knock is False:
        return out
    for bid, (d, a) in sim.nudge(config.stand_nudge).items():
        if d > config.stand_tolerance or a > config.stand_rotation:
            out[bid] = f"falls over at a small knock (moved {d:.2f} m, turned {a:.0f} deg): it cannot stand as seen"
    return out


_ATTEMPTS = (1.0, 1.0, 1.0, 0.66, 0.33, 0.0)   # reach of each attempt's depth draw, then as perceived


def build_sample(scene: Scene, seed: int, sample: int, config: PhysicsConfig,
                 ranges: dict[str, tuple[float, float]] | None = None,
                 model: Uncertainty | None = None, known: frozenset[str] = frozenset()) -> Draw:
    """The settled world of draw `sample`; a draw that does not stand as observed is redrawn.

    A draw contradicts the image when a box moves more than `stand_tolerance` or
    turns more than `stand_rotation` while it settles, or when its overlaps cannot
    be repaired. Later attempts reach less deep (a box turned in the plane swings
    its back corners into its neighbours). When no attempt stands, the attempt
    that moved the fewest boxes comes back with ``stands=False``: the caller must
    say so, never plan on it as if it were the shelf. Boxes in `known` already
    failed every attempt of an earlier sample: a draw in which only they
    contradict the image is not drawn again (each attempt costs a whole world).
    """
    model = model if model is not None else Uncertainty()
    if scene.depth_known:   # a known shelf is the truth: one world, as given
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sim = ShelfSim(scene, config, local=config.prediction_local)
        off = contradictions(sim, config)
        return Draw(sim, (off,) if off else (), not off, off)
    rejected: list[dict[str, str]] = []
    best: ShelfSim | None = None
    best_off: dict[str, str] = {}
    ranges = ranges if ranges is not None else depth_ranges(scene, config)
    as_seen = {b.id: (b.size[1], b.size[1]) for b in scene.boxes if not b.depth_known}
    for attempt, reach in enumerate(_ATTEMPTS + (None,)):
        k = sample + 1000 * attempt
        # the last resort keeps perception's placeholder depths, which perception made valid
        sc = draw_scene(scene, seed, k, model, as_seen if reach is None else ranges, reach or 0.0)
        cfg = draw_config(config, seed, k, model)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                sim = ShelfSim(sc, cfg, local=config.prediction_local)
        except SceneError as exc:  # overlaps past repair, or a world that never comes to rest
            rejected.append({"*": str(exc)})
            continue
        off = contradictions(sim, config)
        if not off or (known and set(off) <= known):
            if best is not None:
                best.close()
            if off:
                rejected.append(off)
            return Draw(sim, tuple(rejected), not off, off)
        rejected.append(off)
        if best is None or len(off) < len(best_off):
            if best is not None:
                best.close()
            best, best_off = sim, off
        else:
            sim.close()
    if best is None:
        raise SceneError(f"no draw of sample {sample} can be built: {rejected[-1].get('*', rejected[-1])}")
    return Draw(best, tuple(rejected), False, best_off)


def not_standing(draw: Draw) -> frozenset[str]:
    """The boxes that contradict the image in the world this draw settled on."""
    return frozenset() if draw.stands else frozenset(b for b in draw.off if b != "*")


def scene_check(draws: Sequence[Draw]) -> dict:
    """Whether the observed shelf stands as seen, from the sample worlds' draws.

    A box is a problem when no attempt of a sample made it stand, in at least
    half of the samples: then no plausible draw of what the camera cannot know
    explains the image. (A box that fails in one sample of ten is explained by
    the others; that sample's world is the attempt that contradicts least.)
    """
    fails: dict[str, list[str]] = {}
    redrawn = 0
    for d in draws:
        redrawn += len(d.rejected)
        for bid in not_standing(d):
            fails.setdefault(bid, []).append(d.off[bid])
    problems = {b: whats[0] for b, whats in fails.items() if 2 * len(whats) >= len(draws)}
    return {"stands_as_seen": not problems, "redrawn": redrawn,
            "samples_not_standing": sum(1 for d in draws if not d.stands),
            "problems": [{"box": b, "what": w} for b, w in sorted(problems.items())],
            # what the first sample world had to repair (overlaps pushed apart, boxes settled)
            "repairs": list(draws[0].repairs) if draws else []}


class _Worlds:
    """Some of the sample worlds (all of them, or one worker's share) and their cached states."""

    def __init__(self, scene: Scene, seed: int, config: PhysicsConfig, indices: Sequence[int],
                 model: Uncertainty | None = None, known: frozenset[str] = frozenset()):
        """`known`: the boxes that did not stand in sample 0 (found here when 0 is in `indices`)."""
        self.seed = seed
        self.local = config.prediction_local
        self.order = {b: i for i, b in enumerate(scene.ids)}
        self.sims: dict[int, ShelfSim] = {}
        self.draws: dict[int, Draw] = {}
        ranges = depth_ranges(scene, config) if not scene.depth_known else None
        try:
            for i in indices:   # sample 0 first: the others learn from it what does not stand
                self.draws[i] = d = build_sample(scene, seed, i, config, ranges, model,
                                                 frozenset() if i == 0 else known)
                self.sims[i] = d.sim
                if i == 0:
                    known = not_standing(d)
        except BaseException:
            self.close()
            raise
        self.states = {i: {frozenset(): sim.snapshot()} for i, sim in self.sims.items()}
        self.new_states = 0

    def state(self, i: int, removed: frozenset[str]):
        st = self.states[i]
        snap = st.get(removed)
        if snap is None:
            sim = self.sims[i]
            sim.restore(st[frozenset()])
            sim.delete_many(sorted(removed, key=self.order.__getitem__), local=self.local)
            snap = sim.snapshot()
            st[removed] = snap
            self.new_states += 1
        return snap

    def pull(self, i: int, removed: frozenset[str], box: str) -> StepResult:
        sim = self.sims[i]
        sim.restore(self.state(i, removed))
        return sim.remove(box, seed=trial_seed(self.seed, i, removed, box), stop_on_collapse=True,
                          local=self.local)

    def preview(self, sequence: Sequence[str], i: int) -> list[StepResult]:
        sim = self.sims[i]
        removed: frozenset[str] = frozenset()
        out = []
        sim.restore(self.states[i][frozenset()])
        try:
            for box in sequence:
                out.append(sim.remove(box, seed=trial_seed(self.seed, i, removed, box), record=True))
                removed = removed | {box}
        finally:
            sim.restore(self.states[i][frozenset()])
        return out

    def close(self) -> None:
        for sim in self.sims.values():
            sim.close()
        self.sims = {}


def _worker(conn) -> None:
    """A pool process: holds one Predictor's share of the sample worlds at a time.

    It lives as long as the parent process: after a Predictor closes, the
    worker closes its worlds (their Bullet clients stay in this process's idle
    list, see planning/sim.py) and waits for the next Predictor's "build".
    """
    worlds: _Worlds | None = None
    try:
        while True:
            msg = conn.recv()
            if msg[0] == "build":
                _, scene, seed, config, indices, model, known = msg
                try:
                    worlds = _Worlds(scene, seed, config, indices, model, known)
                except BaseException as exc:  # reported to the parent, which raises it
                    worlds = None
                    conn.send(("error", exc))
                    continue
                conn.send(("ready", {i: (d.sim.scene, d.rejected, d.stands, d.off, d.repairs)
                                     for i, d in worlds.draws.items()}))
            elif msg[0] == "pull":
                _, removed, box, which = msg
                conn.send(("ok", {i: replace(worlds.pull(i, removed, box), frames=())  # type: ignore[union-attr]
                                  for i in which}))
            elif msg[0] == "preview":
                conn.send(("ok", worlds.preview(msg[1], msg[2])))  # type: ignore[union-attr]
            elif msg[0] == "release":
                if worlds is not None:
                    worlds.close()
                worlds = None
            else:
                break
    except (EOFError, KeyboardInterrupt):
        pass
    finally:
        if worlds is not None:
            worlds.close()


# Idle pool processes of this process, reused by the next Predictor (fork and import cost,
# and the Bullet clients the worker already connected, are paid once per process).
_IDLE_WORKERS: list = []
_IDLE_WORKERS_PID: list[int] = [0]


def _take_worker():
    import multiprocessing as mp
    import os

    if _IDLE_WORKERS_PID[0] != os.getpid():
        _IDLE_WORKERS.clear()
        _IDLE_WORKERS_PID[0] = os.getpid()
    while _IDLE_WORKERS:
        proc, conn = _IDLE_WORKERS.pop()
        if proc.is_alive():
            return proc, conn
    ctx = mp.get_context("fork" if "fork" in mp.get_all_start_methods() else "spawn")
    parent, child = ctx.Pipe()
    proc = ctx.Process(target=_worker, args=(child,), daemon=True)
    proc.start()
    child.close()
    return proc, parent


def _give_back_worker(proc, conn) -> None:
    import os

    try:
        conn.send(("release",))
    except (OSError, BrokenPipeError):
        proc.join(timeout=1)
        return
    if _IDLE_WORKERS_PID[0] == os.getpid() and len(_IDLE_WORKERS) < 8:
        _IDLE_WORKERS.append((proc, conn))
    else:
        try:
            conn.send(("close",))
        except (OSError, BrokenPipeError):
            pass
        proc.join(timeout=5)
        if proc.is_alive():
            proc.terminate()


@dataclass(frozen=True)
class _Stub:
    """A pool worker's `Draw` as the parent sees it (the world stays in the worker)."""

    scene: Scene
    rejected: tuple
    stands: bool
    off: Mapping[str, str]
    repairs: tuple[str, ...]


class Predictor:
    """The planners' oracle: `trial(removed, box) -> StepPrediction` over N depth samples.

    With every depth known, the N samples would be the same world, so one
    world is built and its verdict is the prediction (probabilities 0 or 1).
    `early_stop_risk` (opt-in): stop sampling a candidate once more than that
    fraction of samples collapsed, because it can no longer be safe; the
    reported collapse_prob is then a lower bound that is already over it.
    `workers` > 1 (opt-in) spreads the sample worlds over that many processes
    that live as long as the Predictor; results are identical to `workers=1`.
    """

    def __init__(self, scene: Scene, samples: int = 10, seed: int = 0,
                 config: PhysicsConfig | None = None, *, early_stop_risk: float | None = None,
                 workers: int = 1, model: Uncertainty | None = None):
        if samples < 1:
            raise ValueError(f"samples must be >= 1, got {samples}")
        # the sample worlds run the prediction settings (30 solver iterations, see docs/speed.md);
        # execute_plan and the generator keep the full ones
        self.config = cfg = (config or PhysicsConfig()).for_prediction()
        self.scene = scene
        self.seed = int(seed)
        self.samples = samples
        self.early_stop_risk = early_stop_risk
        self.model = model if model is not None else Uncertainty()
        self._n = samples if not scene.depth_known else 1
        self._order = {b: i for i, b in enumerate(scene.ids)}
        self._local: _Worlds | None = None
        self._pool: list = []
        self._broken = False
        t0 = time.perf_counter()
        workers = max(1, min(int(workers), self._n))
        if workers == 1:
            self._local = _Worlds(scene, self.seed, cfg, range(self._n), self.model)
            self.sample_scenes = [self._local.sims[i].scene for i in range(self._n)]
            self.scene_check = scene_check([self._local.draws[i] for i in range(self._n)])
        else:
            self._start_pool(workers)
        self._cache: dict[tuple[frozenset[str], str], StepPrediction] = {}
        self._runs: dict[tuple[frozenset[str], str], list[StepResult]] = {}
        self.stats = {"build_s": time.perf_counter() - t0, "trials": 0, "cache_hits": 0,
                      "screens": 0, "pulls": 0, "trial_s": 0.0, "workers": workers}

    def _start_pool(self, workers: int) -> None:
        # what does not stand in sample 0 is what the other samples need not redraw for;
        # found here, before the workers start, so every worker count gives the same worlds
        known: frozenset[str] = frozenset()
        if not self.scene.depth_known:
            first = build_sample(self.scene, self.seed, 0, self.config, None, self.model)
            known = not_standing(first)
            first.sim.close()
        shares = [list(range(k, self._n, workers)) for k in range(workers)]
        for share in shares:
            proc, conn = _take_worker()
            self._pool.append((proc, conn, share))
            conn.send(("build", self.scene, self.seed, self.config, share, self.model, known))
        scenes: dict[int, tuple] = {}
        error: BaseException | None = None
        try:
            for _, conn, _ in self._pool:  # every reply is read, so no pipe keeps a stale one
                kind, payload = conn.recv()
                if kind == "error":
                    error = error or payload
                else:
                    scenes.update(payload)
        except BaseException:
            self._broken = True
            self.close()
            raise
        if error is not None:
            self.close()
            raise error
        self.sample_scenes = [scenes[i][0] for i in range(self._n)]
        self.scene_check = scene_check([_Stub(*scenes[i]) for i in range(self._n)])  # type: ignore[list-item]

    @property
    def worlds(self) -> int:
        return self._n

    @property
    def sims(self) -> list[ShelfSim]:
        """The sample worlds of this process (empty when a pool holds them)."""
        return [self._local.sims[i] for i in range(self._n)] if self._local else []

    def _check(self, removed: frozenset[str], box: str) -> None:
        if box not in self._order:
            raise SceneError(f"unknown box id {box!r}; the scene has {', '.join(self.scene.ids)}")
        if box in removed:
            raise ValueError(f"box {box!r} is already removed")
        for b in removed:
            if b not in self._order:
                raise SceneError(f"unknown box id {b!r}; the scene has {', '.join(self.scene.ids)}")

    def _run(self, key: tuple[frozenset[str], str], upto: int) -> list[StepResult]:
        """The per-sample results of `key` for samples 0..upto-1 (at least), run as needed.

        Every sample's result is a pure function of (seed, sample, removed, box), so
        results run earlier, in whatever chunks, are reused as they are. A pool runs
        one sample per worker at a time (some may be ahead of what was asked for).
        """
        runs = self._runs.get(key)
        if runs is None:
            self._check(*key)
            runs = self._runs[key] = []
        m = len(runs)
        upto = min(upto, self._n)
        if upto <= m:
            return runs
        t0 = time.perf_counter()
        removed, box = key
        if self._local is not None:
            for i in range(m, upto):
                runs.append(self._local.pull(i, removed, box))
        else:
            hi = min(self._n, max(upto, m + len(self._pool)))
            busy = []
            merged: dict[int, StepResult] = {}
            try:
                for _, conn, share in self._pool:
                    which = [i for i in share if m <= i < hi]
                    if which:
                        conn.send(("pull", removed, box, which))
                        busy.append(conn)
                for conn in busy:
                    merged.update(conn.recv()[1])
            except BaseException:  # a reply may be left in a pipe: these workers are not reused
                self._broken = True
                raise
            runs.extend(merged[i] for i in range(m, hi))
        self.stats["pulls"] += len(runs) - m
        self.stats["trial_s"] += time.perf_counter() - t0
        return runs

    def trial(self, removed: frozenset[str], box: str) -> StepPrediction:
        """Pull `box` from the scene with `removed` taken away, in every depth sample."""
        removed = frozenset(removed)
        key = (removed, box)
        hit = self._cache.get(key)
        if hit is not None:
            self.stats["cache_hits"] += 1
            return hit
        if self.early_stop_risk is not None:
            pred = self.screen(removed, box, self.early_stop_risk)
        else:
            pred = self._aggregate(box, self._run(key, self._n), self._n)
        self._cache[key] = pred
        self.stats["trials"] += 1
        return pred

    __call__ = trial

    def screen(self, removed: frozenset[str], box: str, risk: float = 0.0) -> StepPrediction:
        """Sample `box` only until it can no longer be safe at `risk` (sequential sampling).

        Samples run in order 0, 1, ...; as soon as more than `risk * N` of them
        collapsed (or collided), the candidate is unsafe whatever the remaining
        samples say, and the prediction over that prefix comes back: its
        probabilities are lower bounds (counts / N), already over `risk`. A
        prediction at or under `risk` always covers every sample, so it is exact.
        The prefix is fixed by the samples alone, so the answer is the same
        whichever worker count ran them.
        """
        removed = frozenset(removed)
        key = (removed, box)
        n = self._n
        limit = risk * n + 1e-9
        c = x = m = 0
        runs = self._runs.get(key, [])
        while m < n:
            if m >= len(runs):
                runs = self._run(key, m + 1)
            r = runs[m]
            m += 1
            c += bool(r.collapsed)
            x += bool(r.collided or r.note.startswith("stuck"))
            if max(c, x) > limit:
                break
        self.stats["screens"] += 1
        return self._aggregate(box, runs[:m], n)

    def risk_bound(self, removed: frozenset[str], box: str) -> tuple[float, bool]:
        """(lower bound of the risk from the samples run so far, whether that is all of them)."""
        runs = self._runs.get((frozenset(removed), box), [])
        c = sum(1 for r in runs if r.collapsed)
        x = sum(1 for r in runs if r.collided or r.note.startswith("stuck"))
        return max(c, x) / self._n, len(runs) >= self._n

    def least_risky(self, removed: frozenset[str], boxes: Sequence[str]) -> str:
        """The box of `boxes` with the lowest risk (first in the given order on a tie).

        Exact, but lazily: the candidate with the lowest lower bound gets one more
        sample until the lowest one has all its samples; its risk is then exact and
        no other can be lower (their lower bounds already are not).
        """
        removed = frozenset(removed)
        if not boxes:
            raise ValueError("least_risky needs at least one box")
        while True:
            best = min(range(len(boxes)), key=lambda k: (self.risk_bound(removed, boxes[k])[0], k))
            key = (removed, boxes[best])
            runs = self._runs.get(key, [])
            if len(runs) >= self._n:
                return boxes[best]
            self._run(key, len(runs) + 1)

    def results(self, removed: frozenset[str], box: str) -> list[StepResult]:
        """The per-sample StepResults behind a trial (runs them if needed)."""
        return list(self._run((frozenset(removed), box), self._n))

    def _aggregate(self, box: str, results: list[StepResult], n: int) -> StepPrediction:
        order = self._order
        collapse = sum(1 for r in results if r.collapsed)
        collision = sum(1 for r in results if r.collided or r.note.startswith("stuck"))
        first = Counter(r.collapsed[0] for r in results if r.collapsed)
        first_seen: dict[str, int] = {}
        seen: dict[str, int] = {}
        freq: Counter = Counter()
        for i, r in enumerate(results):
            if r.collapsed:
                first_seen.setdefault(r.collapsed[0], i)
            for b in dict.fromkeys(r.collapsed + r.collided):
                freq[b] += 1
                seen.setdefault(b, i)
        lead = sorted(first, key=lambda b: (-first[b], first_seen[b], order[b]))
        rest = sorted((b for b in freq if b not in first), key=lambda b: (-freq[b], seen[b], order[b]))
        return StepPrediction(box, collapse / n, collision / n, tuple(lead + rest))

    def preview(self, sequence: Sequence[str], sample: int = 0) -> list[StepResult]:
        """Run a whole sequence in one sample world, recording frames (~30 fps of sim time)."""
        if not 0 <= sample < self._n:
            raise ValueError(f"sample must be in 0..{self._n - 1}, got {sample}")
        if self._local is not None:
            return self._local.preview(sequence, sample)
        for _, conn, share in self._pool:
            if sample in share:
                conn.send(("preview", list(sequence), sample))
                return conn.recv()[1]
        raise AssertionError("no worker holds sample")  # pragma: no cover

    def close(self) -> None:
        if getattr(self, "_local", None) is not None:
            self._local.close()
            self._local = None
        for proc, conn, _ in getattr(self, "_pool", []):
            if getattr(self, "_broken", False):
                proc.terminate()
                proc.join(timeout=5)
            else:
                _give_back_worker(proc, conn)
        self._pool = []

    def __enter__(self) -> "Predictor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
