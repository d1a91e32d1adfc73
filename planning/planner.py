"""The one entry point that turns a scene and a task into a `Plan`.

The CLI, the benchmark and the console all call `make_plan`; it validates the
request, builds (or reuses) the physics `Predictor`, runs the chosen search
and records, for every step, what the physics predicts, so that plans of the
two planners can be compared step by step.
"""
from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable

from shelfpick.perception.errors import FormatError
from shelfpick.perception.scene import Scene
from shelfpick.planning.clear import prefer_baseline, search_clear, visit_order
from shelfpick.planning.contradicted import verdict as contradicted_verdict
from shelfpick.planning.calibration import DEFAULT_MAX_PLAN_RISK, Calibration, calibration_for
from shelfpick.planning.extract import CountingOracle, search_extract, success_prob
from shelfpick.planning.gate import GateResult, gate
from shelfpick.planning.heuristic import heuristic_order
from shelfpick.planning.oracle import Predicting, Screening, Verifying
from shelfpick.planning.plan import PLANNERS, TASKS, Plan, StepPrediction
from shelfpick.planning.predict import Predictor
from shelfpick.planning.reorder import reorder_extraction
from shelfpick.planning.set_aside import SetAside, build_setting_aside
from shelfpick.planning.shorten import shorten_extraction
from shelfpick.planning.uncertainty import Uncertainty
from shelfpick.planning.unexplained import verdict as unexplained_verdict

if TYPE_CHECKING:  # pragma: no cover
    from shelfpick.planning.bullet_clients import ClientPool
    from shelfpick.planning.physics import PhysicsConfig
    from shelfpick.planning.worker_pool import WorkerPool



def check_request(scene: Scene, task: str, target: str | None, planner: str, samples: int,
                  risk: float, origin: str = "") -> None:
    """Refuse a request the planners cannot serve, naming the argument and its value."""
    if task not in TASKS:
        raise FormatError(origin, "task", f"expected one of {', '.join(TASKS)}, got {task!r}")
    if planner not in PLANNERS:
        raise FormatError(origin, "planner", f"expected one of {', '.join(PLANNERS)}, got {planner!r}")
    if task == "extract":
        if target is None:
            raise FormatError(origin, "target", "an extract task needs a target box id (--target ID)")
        scene.require(target, origin)
    elif target is not None:
        raise FormatError(origin, "target", f"a clear task takes no target, got {target!r}")
    if isinstance(samples, bool) or not isinstance(samples, int) or samples < 1:
        raise FormatError(origin, "samples", f"expected a positive integer, got {samples!r}")
    if isinstance(risk, bool) or not isinstance(risk, (int, float)) or not (0.0 <= risk <= 1.0):
        raise FormatError(origin, "risk", f"expected a probability in [0, 1], got {risk!r}")


def evaluate_sequence(sequence: tuple[str, ...],
                      trial: Callable[[frozenset[str], str], StepPrediction]) -> tuple[StepPrediction, ...]:
    """What the physics predicts for each step of a fixed sequence (the baseline's)."""
    out = []
    removed: frozenset[str] = frozenset()
    for box in sequence:
        out.append(trial(removed, box))
        removed = removed | {box}
    return tuple(out)


@dataclass(frozen=True)
class _Request:
    """make_plan's arguments in one value, built once: what its helpers pass along unchanged, so
    each takes the request and only what is its own. `scene` is the one planned on (the given
    one less any faces set aside, once make_plan's own predictor has been built)."""

    scene: Scene
    task: str
    target: str | None
    planner: str
    samples: int
    seed: int
    risk: float
    config: "PhysicsConfig | None"
    budget_s: float | None
    origin: str
    workers: int
    model: Uncertainty | None
    pool: "WorkerPool | None"
    clients: "ClientPool | None"
    verify: int
    max_plan_risk: float
    calibration: Calibration | None


def _search(req: _Request, predictor: Predicting, sampling: Screening | None,
            t0: float) -> tuple[tuple[str, ...], tuple[StepPrediction, ...], bool, dict[str, float], int]:
    """Run the planner: (sequence, predicted, timed out, timing, distinct questions asked of the physics)."""
    scene, task, target, risk, budget_s = req.scene, req.task, req.target, req.risk, req.budget_s
    oracle = CountingOracle(predictor.trial)
    screened: set[tuple[frozenset[str], str]] = set()
    if req.planner == "heuristic":
        t1 = time.perf_counter()
        sequence = heuristic_order(scene, target)
        t_plan = time.perf_counter() - t1
        predicted = evaluate_sequence(sequence, oracle)
        timing = {"planning_s": t_plan, "prediction_s": time.perf_counter() - t1 - t_plan}
        return tuple(sequence), tuple(predicted), False, timing, len(oracle.keys)
    deadline = None if budget_s is None else time.monotonic() + budget_s
    # the fast path (docs/speed.md): a Predictor samples a candidate only until it
    # can no longer be safe, and finds the least risky box without sampling all
    # (`bounded`: the same, with the most risk a step may carry given by the caller)
    fast = least = bounded = None
    worlds = sampling.worlds if sampling is not None else None   # what the plans' chances are counted over
    if sampling is not None:
        screen = sampling.screen

        def bounded(r: frozenset[str], b: str, bound: float) -> StepPrediction:
            screened.add((frozenset(r), b))
            return screen(r, b, bound)

        def fast(r: frozenset[str], b: str) -> StepPrediction:
            return bounded(r, b, risk)
        least = sampling.least_risky
    if task == "extract":
        res = search_extract(scene.ids, target, oracle, risk=risk, deadline=deadline,  # type: ignore[arg-type]
                             screen=fast, bounds=getattr(sampling, "risk_interval", None),
                             more=getattr(sampling, "sample_more", None))
        passed = (lambda: deadline is not None and time.monotonic() >= deadline)
        res = shorten_extraction(res, oracle, risk, screen=bounded, passed=passed)
        res = reorder_extraction(res, scene, oracle, risk, screen=bounded, passed=passed, worlds=worlds)
    else:
        res = search_clear(visit_order(scene), oracle, risk=risk, deadline=deadline,
                           screen=fast, least_risky=least, samples=worlds)
        if not res.timed_out:
            res = prefer_baseline(res, heuristic_order(scene, None), oracle, risk, screen=bounded, worlds=worlds)
    timing = {"planning_s": time.perf_counter() - t0}
    return (tuple(res.sequence), tuple(res.predicted), res.timed_out, timing,
            len(screened | oracle.keys))


def _verdict(predicted: tuple[StepPrediction, ...], risk: float, search: dict[str, Any],
             check: Any, gated: GateResult | None = None) -> tuple[bool, dict[str, Any]]:
    """(safe, the plan's extra): the calibrated chance of a collapse surely below the plan
    threshold (`gated`; without a gate, every step within `risk`), on a shelf that stands as seen."""
    safe = gated.safe if gated is not None else all(p.risk <= risk for p in predicted)
    extra: dict[str, Any] = {"search": search}
    if isinstance(check, dict):
        extra["scene_check"] = check
        # a shelf that does not stand as seen was not observed right: nothing planned on it is safe
        safe = safe and bool(check.get("stands_as_seen", True))
    return safe, extra


@dataclass(frozen=True)
class _Searched:
    """What the search and the gate found, before the verdicts: make_plan's middle in one value."""

    sequence: tuple[str, ...]
    predicted: tuple[StepPrediction, ...]
    timing: dict[str, float]
    check: Any                       # the predictor's scene check (None without a Screening one)
    gated: GateResult | None


def _check_plan_request(req: _Request) -> None:
    """Refuse what make_plan cannot serve before any world is built: the plan threshold, the
    request, then the budget, each named with its value."""
    max_plan_risk, budget_s, origin = req.max_plan_risk, req.budget_s, req.origin
    if isinstance(max_plan_risk, bool) or not isinstance(max_plan_risk, (int, float)) \
            or not 0.0 < max_plan_risk <= 1.0:
        raise FormatError(origin, "max_plan_risk", f"expected a probability in (0, 1], got {max_plan_risk!r}")
    check_request(req.scene, req.task, req.target, req.planner, req.samples, req.risk, origin)
    if budget_s is not None and (not math.isfinite(budget_s) or budget_s <= 0):
        raise FormatError(origin, "budget", f"expected a positive number of seconds, got {budget_s!r}")


def _own_predictor(req: _Request, search: dict[str, Any]) -> tuple[Predicting, SetAside]:
    """A Predictor of make_plan's own, with the faces no world can hold set aside as unexplained
    matter (not the whole shelf refused); the plan records the model its worlds were drawn from."""
    model = req.model
    search["uncertainty"] = (model if model is not None else Uncertainty()).to_json()
    return build_setting_aside(
        req.scene, req.target, lambda sc: Predictor(sc, samples=req.samples, seed=req.seed, config=req.config,
                                                    workers=req.workers, model=model, pool=req.pool,
                                                    clients=req.clients))


def _warn_repairs(sampling: Screening) -> None:
    """With known depths every world has the scene's own geometry, so what the predictor repaired
    (kept quiet in its worlds) is worth telling the user; reported where make_plan was called."""
    for msg in sampling.scene_check.get("repairs", ()):
        warnings.warn(f"scene repaired: {msg}", stacklevel=3)


def _record_search(search: dict[str, Any], sampling: Screening | None, stats: Any, calls: int,
                   timed_out: bool, pulls0: int, budget_s: float | None) -> None:
    """What the search cost, in the plan's extra: the distinct questions asked of the physics
    (screened or fully sampled), the pulls actually run, the budget and the worlds."""
    search.update({"oracle_calls": calls, "timed_out": timed_out})
    if isinstance(stats, dict) and "pulls" in stats:
        search["pulls"] = stats["pulls"] - pulls0  # physics pulls (samples actually run)
    if budget_s is not None:
        search["budget_s"] = budget_s
    if sampling is not None:
        search["worlds"] = sampling.worlds


def _gate_or_verify(req: _Request, predictor: Predicting, sampling: Screening | None, found: _Searched,
                    search: dict[str, Any]) -> _Searched:
    """`found` (the search's, no gate yet) asked of more worlds: by the calibrated gate where the
    predictor can, else (a plan safe by the search's worlds) by plain verification; as it was otherwise."""
    sequence, predicted, check, timing, verify = found.sequence, found.predicted, found.check, found.timing, req.verify
    safe, _ = _verdict(predicted, req.risk, search, check)
    if hasattr(predictor, "plan_results") and sampling is not None and sequence:
        t1 = time.perf_counter()
        stands = bool((check or {}).get("stands_as_seen", True))
        pulls = getattr(getattr(predictor, "model", None), "pull_modes", Uncertainty().pull_modes)
        gated = gate(predictor, sequence, stands, req.calibration or calibration_for(pulls),
                     float(req.max_plan_risk), sampling.worlds, sampling.worlds + max(0, int(verify)),
                     skip=sampling.worlds)
        timing["verify_s"] = time.perf_counter() - t1
        search["verified_worlds"] = gated.worlds
        return replace(found, predicted=gated.predicted, gated=gated)
    if safe and verify and isinstance(predictor, Verifying):
        t1 = time.perf_counter()
        predicted = predictor.verify(sequence, verify)
        timing["verify_s"] = time.perf_counter() - t1
        search["verified_worlds"] = predictor.verified_worlds
    return replace(found, predicted=predicted)


def _search_and_gate(req: _Request, predictor: Predicting, sampling: Screening | None, search: dict[str, Any],
                     t0: float) -> _Searched:
    """The search, what it cost, then the gate: everything that needs the predictor open
    (`t0`: when make_plan began, which the setup and planning times count from)."""
    t_ready = time.perf_counter()
    stats = sampling.stats if sampling is not None else None
    pulls0 = stats.get("pulls", 0) if isinstance(stats, dict) else 0
    sequence, predicted, timed_out, timing, calls = _search(req, predictor, sampling, t0)
    timing["setup_s"] = t_ready - t0
    _record_search(search, sampling, stats, calls, timed_out, pulls0, req.budget_s)
    check = sampling.scene_check if sampling is not None else None
    return _gate_or_verify(req, predictor, sampling, _Searched(sequence, predicted, timing, check, None), search)


def _judged(req: _Request, search: dict[str, Any], found: _Searched) -> Plan:
    """The plan with its verdict: the chances it succeeds, then safe only if the gate (or every
    step) says so, no step touches unexplained matter and none stands on a doubted face."""
    predicted, gated, scene = found.predicted, found.gated, req.scene
    search["worlds_success_prob"] = success_prob(predicted)   # prod(1 - step risk) over the worlds
    search["success_prob"] = 1.0 - gated.probability if gated is not None else success_prob(predicted)
    search["max_plan_risk"] = float(req.max_plan_risk)
    if gated is not None:
        search["plan_risk"] = gated.to_json()
    safe, extra = _verdict(predicted, req.risk, search, found.check, gated)
    safe, extra = unexplained_verdict(scene, found.sequence, predicted, safe, extra)   # a plan touching it is not safe
    safe, extra = contradicted_verdict(scene, found.sequence, predicted, safe, extra)  # nor one on a doubted face
    return Plan(req.task, req.target, req.planner, tuple(found.sequence), tuple(predicted), safe, found.timing,
                req.seed, extra)


def make_plan(scene: Scene, task: str, target: str | None = None, planner: str = "physics",
              samples: int = 10, seed: int = 0, risk: float = 0.0,
              config: "PhysicsConfig | None" = None, predictor: Predicting | None = None,
              *, budget_s: float | None = None, origin: str = "", workers: int = 1,
              model: Uncertainty | None = None, pool: "WorkerPool | None" = None,
              clients: "ClientPool | None" = None, verify: int = 30,
              max_plan_risk: float = DEFAULT_MAX_PLAN_RISK, calibration: Calibration | None = None) -> Plan:
    """Plan `task` ("extract" with `target`, or "clear") with the `physics` or `heuristic` planner.

    `predictor` (a `planning.oracle.Predicting`; a `Screening` one is used to the full) is
    reused when given (the console and the benchmark keep one per scene);
    otherwise one is built from `scene` with `samples` draws of what the camera
    cannot know (`model`, default `Uncertainty()`: depth, mass, friction, face
    error, the pull) and `seed` (over `workers` processes of `pool`, or of a pool
    of its own: same plan, less wait; Bullet clients from `clients` when given),
    and closed afterwards. `budget_s` bounds the physics search; when it runs out
    the plan says so (``extra["search"]["timed_out"]``). The plan found is then gated
    (`planning.gate`): the worlds in which some step fails give a calibrated chance of a
    collapse (`calibration`, default the fitted one) with an interval, asked of up to `verify`
    more worlds while the interval straddles `max_plan_risk`; the plan is safe when the upper
    end is below it. Its predictions are then over every world it was asked of.
    """
    req = _Request(scene=scene, task=task, target=target, planner=planner, samples=samples, seed=seed, risk=risk,
                   config=config, budget_s=budget_s, origin=origin, workers=workers, model=model, pool=pool,
                   clients=clients, verify=verify, max_plan_risk=max_plan_risk, calibration=calibration)
    _check_plan_request(req)
    t0 = time.perf_counter()
    search: dict[str, Any] = {"risk_threshold": float(risk), "samples": samples}
    if not scene.boxes:  # clear of an empty shelf: nothing to do
        return Plan(task, target, planner, (), (), True, {"planning_s": 0.0}, seed, {"search": search})
    own = predictor is None
    aside = SetAside(scene, scene)
    if own:
        predictor, aside = _own_predictor(req, search)
        req = replace(req, scene=aside.planned)
    sampling = predictor if isinstance(predictor, Screening) else None
    try:
        if own and req.scene.depth_known and sampling is not None:
            _warn_repairs(sampling)
        found = _search_and_gate(req, predictor, sampling, search, t0)
    finally:
        if own:
            predictor.close()  # type: ignore[union-attr]
    plan = _judged(req, search, found)
    # every plan says what made it (version, scene hash, physics), whoever asked: CLI, console, bench;
    # with faces set aside, what and why, and the hash of the scene it was given
    return aside.record(plan.with_provenance(req.scene, config, samples, risk))
