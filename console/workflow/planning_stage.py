"""Planning: both planners on the perceived scene, in a background worker, recorded before they count."""
from __future__ import annotations

import threading
import time
import traceback
from dataclasses import replace
from typing import TYPE_CHECKING

from shelfpick.perception.scene import Scene
from shelfpick.planning.plan import PLANNERS, Plan

from shelfpick.console.workflow.core import WorkflowCore, close_quietly
from shelfpick.console.workflow.run_json import step_json
from shelfpick.console.workflow.state import PlanEntry, State, problem_text, scene_problems

if TYPE_CHECKING:
    from shelfpick.planning.bullet_clients import ClientPool
    from shelfpick.planning.predict import Predictor
    from shelfpick.planning.set_aside import SetAside


class PlanningStage(WorkflowCore):
    """`plan()` and its worker: plans for the current capture, dropped if a new capture arrives meanwhile."""

    def plan(self, task: str, wait: bool = False) -> State:
        """Run both planners on the perceived scene in a background worker."""
        if task not in ("extract", "clear"):
            self._refuse(f"unknown task {task!r}; expected extract or clear")
        with self._lock:
            st = self._state
            if self._capturing:
                self._refuse("planning refused: a capture is running")
            self._held("planning")
            if st.scene is None or not st.scene.boxes:
                self._refuse("nothing to plan: capture a shelf with boxes first")
            if st.needs_recapture:
                self._refuse("the shelf has changed since this capture: press `Capture` again")
            if st.planning:
                self._refuse("planning is already running; wait for it to finish")
            if self._plan_thread is not None and self._plan_thread.is_alive():
                self._refuse("the preview of the last plans is still being recorded; press again in a moment")
            if task == "extract" and st.target is None:
                self._refuse("select a target box first")
            target = st.target if task == "extract" else None
            gen = self._generation
            scene, sid = st.scene, st.session_id
            self._plan_thread = threading.Thread(target=self._plan_worker, name="shelfpick-plan",
                                                 args=(gen, scene, sid, task, target), daemon=True)
            keep = {k: e for k, e in st.plans.items() if k == "continue"}
            self._set(planning=True, task=task, plans=keep, approved=None, approval=None, progress=0.0,
                      progress_text="starting", scene_problems=(), repairs=(), error=None,
                      message=f"planning {task}" + (f" {target}" if target else "") + "...")
            thread = self._plan_thread
        thread.start()
        if wait:
            thread.join()
        return self.state

    def wait_planning(self, timeout: float | None = None) -> State:
        t = self._plan_thread
        if t is not None:
            t.join(timeout)
        return self.state

    def _progress(self, gen: int, frac: float, text: str) -> None:
        with self._lock:
            if gen == self._generation:
                self._set(progress=frac, progress_text=text)

    def _predictor_for(self, gen: int, scene: Scene, target: str | None,
                       clients: ClientPool) -> tuple[Predictor, int, SetAside]:
        """The Predictor of this capture: the one the last plan of it used (its sample worlds built,
        its answers known: the same plans, sooner), else a new one; with the epoch it was taken in
        and the faces set aside for it (planning/set_aside.py: faces no world can hold become
        unexplained matter, as `shelfpick plan` does)."""
        from shelfpick.planning.predict import Predictor
        from shelfpick.planning.set_aside import build_setting_aside

        with self._lock:
            kept, self._kept = self._kept, None
            epoch = self._epoch
        if kept is not None and kept[0] == gen and kept[2].given is scene and kept[1].usable():
            try:
                kept[2].refuse(target)
            except Exception:
                close_quietly(kept[1])
                raise
            return kept[1], epoch, kept[2]
        if kept is not None:
            close_quietly(kept[1])
        self._progress(gen, 0.05, f"building {self.samples} depth samples")
        predictor, aside = build_setting_aside(scene, target, lambda sc: Predictor(
            sc, samples=self.samples, seed=self.seed, workers=self.workers, clients=clients,
            model=self.priors.model()))
        return predictor, epoch, aside

    def _keep(self, gen: int, epoch: int, predictor: Predictor, aside: SetAside) -> None:
        """Keep `predictor` for the next plan of this capture; closed when that is over."""
        with self._lock:
            if gen == self._generation and epoch == self._epoch and self._kept is None:
                self._kept = (gen, predictor, aside)
                return
        close_quietly(predictor)

    def _plan_worker(self, gen: int, scene: Scene, sid: int | None, task: str, target: str | None) -> None:
        predictor, epoch, ok, aside = None, 0, False, None
        with self._lock:     # this plan's clients, whatever close() does meanwhile (_plan_pool_done)
            pool = self._planning_pool = self._client_pool()
        try:
            t_setup = time.perf_counter()
            predictor, epoch, aside = self._predictor_for(gen, scene, target, pool)
            t_setup = time.perf_counter() - t_setup     # shared by both planners; charged to physics
            repairs = tuple(str(r) for r in getattr((predictor.sims or [None])[0], "repairs", ()) or ())
            entries = {p: self._one_plan(gen, i, p, aside, task, target, predictor, t_setup, repairs)
                       for i, p in enumerate(PLANNERS)}
            for e in entries.values():
                if sid is not None and self._record(f"the {e.plan.planner} plan", self.store.add_plan, sid,
                                                    e.plan, [step_json(r) for r in e.preview]) is not None:
                    with self._lock:
                        self._recorded.add((sid, e.hash))
            self._plans_ready(gen, entries, repairs)
            ok = True
            self._show_collapse_worlds(gen, entries, predictor, sid)
        except Exception as exc:  # noqa: BLE001 - shown in the page, the server keeps running
            traceback.print_exc()
            with self._lock:
                if gen == self._generation:
                    self._set(planning=False, progress=0.0, progress_text="failed",
                              error=f"planning failed: {exc}")
        finally:
            if predictor is not None and ok and aside is not None:
                self._keep(gen, epoch, predictor, aside)
            elif predictor is not None:      # a predictor a failure went through is not trusted again
                close_quietly(predictor)
            self._plan_pool_done()
            with self._lock:
                if self._state.planning and gen != self._generation:
                    self._state = replace(self._state, planning=False)

    def _one_plan(self, gen: int, i: int, planner: str, aside: SetAside, task: str, target: str | None,
                  predictor: Predictor, t_setup: float, repairs: tuple[str, ...]) -> PlanEntry:
        """One planner's plan on the capture's scene (`aside.given`), made on `aside.planned`."""
        from shelfpick.planning.planner import make_plan

        scene = aside.given
        n = len(PLANNERS)
        self._progress(gen, 0.1 + 0.85 * i / n, f"{planner} planner: searching")
        t0 = time.perf_counter()
        plan = aside.record(make_plan(aside.planned, task, target, planner=planner, samples=self.samples,
                                      seed=self.seed, predictor=predictor, max_plan_risk=self.priors.max_plan_risk))
        timing = dict(plan.timing)
        timing.setdefault("planning_s", time.perf_counter() - t0)
        if planner == "physics":
            timing["setup_s"] = timing.get("setup_s", 0.0) + t_setup
        extra = dict(plan.extra)
        if repairs:
            extra["repairs"] = list(repairs)       # stored with the plan, shown in the replay
        plan = replace(plan, timing=timing, extra=extra)
        self._progress(gen, 0.1 + 0.85 * (i + 0.6) / n, f"{planner} planner: recording preview")
        preview = tuple(predictor.preview(plan.sequence, 0)) if plan.sequence else ()
        from shelfpick.planning.predicted import predicted_shelves

        shelves = tuple(predicted_shelves(scene, plan.sequence, preview)) if preview else ()
        # what the operator waited for this plan (search, risks, preview), shown as its planning time
        plan = replace(plan, timing={**plan.timing, "wall_s": time.perf_counter() - t0})
        return PlanEntry(plan, plan.content_hash(), preview, shelves)

    def _show_collapse_worlds(self, gen: int, entries: dict[str, PlanEntry], predictor: Predictor,
                              sid: int | None = None) -> None:
        """After the plans are shown: each risky step recorded in a world where it collapses, for the
        preview. Done after the click's answer (it costs a pull sequence per risky step); the plans
        are the same (same hashes, recorded as they were), they only gain what the preview shows."""
        try:
            worlds = {p: collapse_worlds(predictor, e.plan) for p, e in entries.items() if e.preview}
        except Exception:  # noqa: BLE001 - the preview then shows the first world only, as before
            traceback.print_exc()
            return
        if not any(worlds.values()):
            return
        for p, w in worlds.items():     # stored with the plan's preview: the replay and HTML show them too
            if w and sid is not None and (sid, entries[p].hash) in self._recorded:
                self._record(f"the {p} plan's collapse worlds", self.store.add_preview_worlds, sid,
                             entries[p].hash, p, {k: {**d, "result": step_json(d["result"])
                                                      if d["result"] is not None else None} for k, d in w.items()})
        with self._lock:
            now = self._state.plans
            if gen != self._generation or any(now.get(p) is not e for p, e in entries.items()):
                return          # a new capture, target or plan meanwhile: these are not shown any more
            self._set(plans={**now, **{p: replace(e, collapse_steps=worlds[p]) for p, e in entries.items()
                                       if worlds.get(p)}})

    def _plans_ready(self, gen: int, entries: dict[str, PlanEntry], repairs: tuple[str, ...]) -> None:
        phys = entries["physics"].plan
        problems = scene_problems(phys)
        with self._lock:
            if gen != self._generation:
                return  # a new capture arrived meanwhile: these plans are for the old shelf
            err = None
            if problems:
                err = ("the shelf does not stand as seen: " + "; ".join(problem_text(p) for p in problems)
                       + ". No plan on it is safe: check the shelf and capture again, or a supervisor "
                         "approves only by accepting the predicted risk")
            elif not phys.safe:
                err = (f"no safe plan: the least risky sequence still has a predicted collapse "
                       f"risk of {100 * phys.risk:.0f}%; a supervisor may approve it only by "
                       f"accepting that risk. Or rearrange the shelf and capture again")
            cont = self._state.plans.get("continue")   # continuing the held plan stays on offer
            if cont is not None:
                entries = {**entries, "continue": cont}
            self._set(plans=entries, planning=False, progress=1.0, progress_text="done", error=err,
                      scene_problems=problems, repairs=repairs,
                      message="plans ready: compare them, preview, then a supervisor approves one")


def collapse_worlds(predictor: Predictor, plan: Plan) -> dict[int, dict]:
    """For each step predicted to collapse something: that step recorded in a sample world where it does.

    The preview (and the predicted shelves the looks compare with) is the first
    sample world, where a step at 10-40 % risk mostly holds; the operator should
    see what the risk is. Returns step -> {"world", "collapsed_in", "of", "result"}:
    the step's recorded pull in the first world whose trial collapsed, replayed from
    the plan's start in that world (a world where the replay does not collapse is
    passed over; none reproduced: the step is left out, the page says the count only).
    """
    out: dict[int, dict] = {}
    removed: frozenset[str] = frozenset()
    for k, (box, pred) in enumerate(zip(plan.sequence, plan.predicted)):
        if pred.collapse_prob > 0:
            results = predictor.results(removed, box)
            fell = [w for w, r in enumerate(results) if r.collapsed]
            doc = {"world": None, "collapsed_in": len(fell), "of": len(results), "result": None}
            for w in fell[:2]:
                rec = predictor.preview(plan.sequence[:k + 1], w)[k]
                if rec.collapsed:
                    doc.update(world=w, result=rec)
                    break
            if fell:
                out[k] = doc
        removed = removed | {box}
    return out


__all__ = ["PlanningStage", "collapse_worlds"]
