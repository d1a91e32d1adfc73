"""The planners' oracle: a removal's collapse and collision risk over sample worlds.

A camera sees front faces only: a box's depth and mass, the friction and the
robot's exact pull are unknown. A `Predictor` judges every removal in N sample
worlds, each one draw of those unknowns (`planning/uncertainty.py`, built by
`planning/sample_worlds.py`), and its prediction is the aggregate. The worlds
live in this process or, with `workers` > 1, in a `WorkerPool` (results are
identical either way).
"""
from __future__ import annotations

import time
from collections import Counter
from typing import Callable, Iterable, Sequence

from shelfpick.perception.errors import SceneError
from shelfpick.perception.scene import Scene
from shelfpick.planning.bullet_clients import ClientPool
from shelfpick.planning.physics import PhysicsConfig
from shelfpick.planning.plan import StepPrediction
from shelfpick.planning.sample_worlds import SampleWorlds, scene_check
from shelfpick.planning.sim import ShelfSim
from shelfpick.planning.step_result import StepResult
from shelfpick.planning.uncertainty import Uncertainty
from shelfpick.planning.worker_pool import Build, Extend, Outbox, Preview, Pull, Worker, WorkerPool

_EXTEND = "extend"   # the Outbox tag of an Extend (a pull's tag is its (removed, box) key)


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
                 workers: int = 1, model: Uncertainty | None = None,
                 pool: WorkerPool | None = None, clients: ClientPool | None = None):
        """`pool`: where the workers come from when `workers` > 1 (a pool of its own, closed with
        the Predictor, when None); `clients`: the Bullet clients of worlds built in this process."""
        if samples < 1:
            raise ValueError(f"samples must be >= 1, got {samples}")
        # the sample worlds run the prediction settings (docs/speed.md);
        # execute_plan and the generator keep the full ones
        self.config = cfg = (config or PhysicsConfig()).for_prediction()
        self.scene = scene
        self.seed = int(seed)
        self.samples = samples
        self.early_stop_risk = early_stop_risk
        self.model = model if model is not None else Uncertainty()
        # a known shelf needs more than one world only while something else is still drawn
        self._drawn = not scene.depth_known or self.model.draws_physics
        self._n = samples if self._drawn else 1
        self.verified_worlds = 0   # the worlds behind the last `verify`
        self._built = self._n   # worlds built: the first `_n` answer every trial, the rest only `verify`
        self._order = {b: i for i, b in enumerate(scene.ids)}
        self._local: SampleWorlds | None = None
        self._workers: list[tuple[Worker, list[int]]] = []
        self._owner: dict[int, Worker] = {}       # sample world -> the worker holding it
        self._outbox = Outbox()                   # pulls and builds sent, replies not read yet
        self._asked: dict[tuple[frozenset[str], str], int] = {}   # key -> samples 0..k-1 sent for
        self._ahead: dict[tuple[frozenset[str], str], dict[int, StepResult]] = {}   # read, not in order yet
        self._broken = False
        t0 = time.perf_counter()
        workers = max(1, min(int(workers), self._n))
        self._pool = pool if pool is not None or workers == 1 else WorkerPool(workers)
        self._own_pool = pool is None and workers > 1
        # in this process without a caller's pool: one of its own, so that a rejected draw's client
        # serves the next draw (a DIRECT connect costs ~10-25 ms); closed with the Predictor
        self._own_clients = ClientPool() if workers == 1 and clients is None else None
        try:
            if workers == 1:
                self._local = SampleWorlds(scene, self.seed, cfg, range(self._n), self.model,
                                           clients=clients or self._own_clients)
                self.sample_scenes = [self._local.sims[i].scene for i in range(self._n)]
                self.scene_check = scene_check([self._local.draws[i] for i in range(self._n)])
            else:
                self._start_workers(workers, clients)
        except BaseException:
            self.close()
            raise
        self._cache: dict[tuple[frozenset[str], str], StepPrediction] = {}
        self._runs: dict[tuple[frozenset[str], str], list[StepResult]] = {}
        self.stats = {"build_s": time.perf_counter() - t0, "trials": 0, "cache_hits": 0,
                      "screens": 0, "pulls": 0, "trial_s": 0.0, "workers": workers}

    def _start_workers(self, workers: int, clients: ClientPool | None) -> None:
        # Each worker builds its whole share in one Build: the same worlds for every worker count,
        # as each world is a function of its sample index alone.
        shares = [list(range(k, self._n, workers)) for k in range(workers)]
        assert self._pool is not None
        for w, share in zip(self._pool.lease(workers), shares):
            self._workers.append((w, share))
            self._owner.update((i, w) for i in share)
            w.send(Build(self.scene, self.seed, self.config, tuple(share), self.model))
        draws = self._gather([w for w, _ in self._workers])
        self.sample_scenes = [draws[i].scene for i in range(self._n)]
        self.scene_check = scene_check([draws[i] for i in range(self._n)])

    def _gather(self, workers: Sequence[Worker]) -> dict:
        """One reply from each of `workers`, merged, as `_merge` reads them."""
        return self._merge(w.recv for w in workers)

    def _merge(self, reads: Iterable[Callable[[], dict]]) -> dict:
        """The replies `reads` return, merged. Every reply is read, so no pipe keeps a stale one; a
        worker's exception is raised after that, a broken pipe at once."""
        merged: dict = {}
        error: BaseException | None = None
        for read in reads:
            try:
                merged.update(read())
            except (EOFError, OSError, KeyboardInterrupt):   # a pipe that may hold a stale reply
                self._broken = True
                raise
            except Exception as exc:  # noqa: BLE001 - the worker's, raised after all replies
                error = error or exc
        if error is not None:
            raise error
        return merged

    def usable(self) -> bool:
        """Whether it can answer again: not closed, no reply left in a pipe, every worker process
        it holds still running (a kept predictor's idle worker may have been killed meanwhile)."""
        if self._broken:
            return False
        if self._workers:
            return all(w.alive() for w, _ in self._workers)
        return self._local is not None

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
        cap = self._n if upto <= self._n else self._built   # search questions never run the extra worlds
        upto = min(upto, cap)
        if upto <= m:
            return runs
        t0 = time.perf_counter()
        removed, box = key
        if self._local is not None:
            for i in range(m, upto):
                runs.append(self._local.pull(i, removed, box))
            self.stats["pulls"] += upto - m
        else:
            self._send(key, upto, cap)
            self._collect([(key, upto)])
        self.stats["trial_s"] += time.perf_counter() - t0
        return runs

    def _send(self, key: tuple[frozenset[str], str], upto: int, cap: int) -> None:
        """Ask the workers for samples up to `upto` of `key` (one more per worker than that, as far
        as `cap`, when fewer: an idle worker runs the next sample), without waiting for the replies.
        What is sent depends only on what was asked before, never on when replies come."""
        a = self._asked.get(key, 0)
        if upto <= a:
            return
        hi = min(cap, max(upto, a + len(self._workers)))
        removed, box = key
        try:
            for w, share in self._workers:
                which = tuple(i for i in share if a <= i < hi)
                if which:
                    self._outbox.send(w, Pull(removed, box, which), key)
        except BaseException:   # a pipe that may hold part of a message: these workers are not reused
            self._broken = True
            raise
        self._asked[key] = hi
        self.stats["pulls"] += hi - a

    def _collect(self, needs: Sequence[tuple[tuple[frozenset[str], str], int]]) -> None:
        """Read replies until every (key, upto) of `needs` has its samples 0..upto-1 in `_runs`
        (sent before); replies to other messages read on the way are kept for their key."""
        try:
            for key, upto in needs:
                runs, ahead = self._runs[key], self._ahead.setdefault(key, {})
                while len(runs) < upto:
                    i = len(runs)
                    if i in ahead:
                        runs.append(ahead.pop(i))
                        continue
                    tag, value = self._outbox.read(self._owner[i])
                    if tag != _EXTEND:
                        self._ahead.setdefault(tag, {}).update(value)
        except BaseException:   # a worker's error, or a pipe left in an unknown state
            self._broken = True
            raise

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
            pred = self._aggregate(box, self._run(key, self._n)[:self._n], self._n)
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

    def _so_far(self, removed: frozenset[str], box: str) -> tuple[int, int]:
        """(failing samples, samples run) of pulling `box`, of the search's worlds run so far."""
        runs = self._runs.get((frozenset(removed), box), [])[:self._n]
        c = sum(1 for r in runs if r.collapsed)
        x = sum(1 for r in runs if r.collided or r.note.startswith("stuck"))
        return max(c, x), len(runs)

    def risk_bound(self, removed: frozenset[str], box: str) -> tuple[float, bool]:
        """(lower bound of the risk from the samples run so far, whether that is all of them)."""
        failed, run = self._so_far(removed, box)
        return failed / self._n, run >= self._n

    def risk_interval(self, removed: frozenset[str], box: str) -> tuple[float, float]:
        """The interval the full risk of pulling `box` lies in, from the samples run so far: every
        sample not run yet may hold or fail (a point once all have run)."""
        failed, run = self._so_far(removed, box)
        return failed / self._n, (failed + self._n - run) / self._n

    def sample_more(self, removed: frozenset[str], box: str) -> None:
        """Run the next sample of pulling `box` (of the search's worlds; nothing once all have run)."""
        key = (frozenset(removed), box)
        self._run(key, len(self._runs.get(key, [])) + 1)

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
        return list(self._run((frozenset(removed), box), self._n)[:self._n])

    def _extend(self, total: int) -> None:
        """Build sample worlds `_built`..`total`-1: the same worlds a Predictor of `total` samples has."""
        new = list(range(self._built, total))
        if not new:
            return
        if self._local is not None:
            self._local.add(new)
        else:
            # sent, not waited for: the pulls in these worlds queue behind it on each pipe, and
            # reading their replies reads its reply first (a failed build is raised there)
            n = len(self._workers)
            try:
                for k, (w, share) in enumerate(self._workers):
                    mine = tuple(i for i in new if i % n == k)
                    if mine:
                        self._outbox.send(w, Extend(mine), _EXTEND)
                        share.extend(mine)
                        self._owner.update((i, w) for i in mine)
            except BaseException:   # a worker may hold part of its new worlds: not reused
                self._broken = True
                raise
        self._built = total

    def verify(self, sequence: Sequence[str], extra: int) -> tuple[StepPrediction, ...]:
        """Each step of `sequence` over the search's worlds and `extra` more (built once, kept).

        The search decides with `worlds` draws; a plan it calls safe is then asked of
        more, so that "safe" rests on `worlds + extra` draws that all held (the extra
        worlds are those a Predictor of that many samples would have, so the answer is
        the same for every worker count). A known shelf with nothing else drawn has one
        world, and nothing more to ask.
        """
        total = self._n + (max(0, int(extra)) if self._drawn else 0)
        self.verified_worlds = total
        steps = self.plan_results(sequence, total)
        return tuple(self._aggregate(box, results, total) for box, results in zip(sequence, steps))

    def plan_results(self, sequence: Sequence[str], total: int) -> list[list[StepResult]]:
        """Every step of `sequence` in the first `total` sample worlds (built as needed, kept: the
        worlds a Predictor of that many samples has), one list of per-world results per step. A
        known shelf with nothing else drawn has one world."""
        total = max(1, int(total)) if self._drawn else self._n
        if total > self._built:
            t0 = time.perf_counter()
            self._extend(total)
            self.stats["build_s"] += time.perf_counter() - t0
        keys = []
        removed: frozenset[str] = frozenset()
        for box in sequence:
            keys.append((removed, box))
            removed = removed | {box}
        if self._local is not None:
            return [list(self._run(key, total)[:total]) for key in keys]
        # every step at once (a step's worlds start from the state with the steps before taken away,
        # not from the pull before): each worker runs its whole share without waiting for the other
        t0 = time.perf_counter()
        cap = self._n if total <= self._n else self._built
        for key in keys:
            if key not in self._runs:
                self._check(*key)
                self._runs[key] = []
            self._send(key, min(total, cap), cap)
        self._collect([(key, min(total, cap)) for key in keys])
        self._read_builds()
        self.stats["trial_s"] += time.perf_counter() - t0
        return [list(self._runs[key][:total]) for key in keys]

    def _read_builds(self) -> None:
        """Read the replies to `Extend`s still oldest on their pipes (a build's error is raised)."""
        try:
            for w, _ in self._workers:
                while self._outbox.pending(w) and self._outbox.oldest(w) == _EXTEND:
                    self._outbox.read(w)
        except BaseException:
            self._broken = True
            raise

    def aggregate(self, box: str, results: list[StepResult]) -> StepPrediction:
        """The prediction of one step over the given per-world results."""
        return self._aggregate(box, results, len(results))

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
        w = self._owner[sample]
        self._read_all(w)
        w.send(Preview(tuple(sequence), sample))
        return w.recv()

    def _read_all(self, w: Worker) -> None:
        """Read every reply pending on `w`'s pipe, keeping the results (before a message of its own)."""
        try:
            while self._outbox.pending(w):
                tag, value = self._outbox.read(w)
                if tag != _EXTEND:
                    self._ahead.setdefault(tag, {}).update(value)
        except BaseException:
            self._broken = True
            raise

    def close(self) -> None:
        if self._local is not None:
            self._local.close()
            self._local = None
        if self._own_clients is not None:
            self._own_clients.close()
            self._own_clients = None
        if self._workers:
            held = [w for w, _ in self._workers]
            # replies nobody waited for (a sample run ahead) must not reach the workers' next owner
            if not self._broken and not self._outbox.drain(held):
                self._broken = True
            self._pool.give_back(held, broken=self._broken)  # type: ignore[union-attr]
            self._workers = []
        if self._own_pool and self._pool is not None:
            self._pool.close()
            self._pool = None

    def __enter__(self) -> "Predictor":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
