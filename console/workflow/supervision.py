"""The supervisor's decisions: approve (takes the run lock) or reject, behind a throttled passphrase.

An approval counts once its decision is committed; every refusal reads the
same whether the passphrase was wrong or the try came too soon.
"""
from __future__ import annotations

import hmac
import time
from typing import Mapping

from shelfpick.console.workflow.core import WorkflowCore
from shelfpick.console.workflow.state import AUTH_REFUSED, PlanEntry, RunLock, State, problem_text


class Supervision(WorkflowCore):
    """`approve()` and `reject()`: exactly this plan for exactly the current capture."""

    def _authenticate(self, plan_hash: str, passphrase: str, who: str, action: str, client: str,
                      planner: str | None = None) -> None:
        """Throttled passphrase check; every refusal reads the same, wrong or too soon. `planner`:
        whose plan the refused decision was for (the page's decisions name it)."""
        secret = self._passphrase.encode()
        given = (passphrase or "").encode()
        verdict = self.throttle.check(client, lambda: hmac.compare_digest(given, secret))
        if verdict:
            return
        st = self.state
        if verdict is False:
            if st.session_id is not None:
                # the store's decisions are approve/reject only: a refused attempt is an event
                self._record("the refused attempt", self.store.add_robot_event, st.session_id, plan_hash,
                             "auth_refused", None, None,
                             {"who": who or "?", "action": action, "client": client,
                              "reason": "wrong supervisor passphrase",
                              "throttled_so_far": self.throttle.throttled})
            with self._lock:
                self._set(decisions=self._state.decisions + (
                    {"decision": "refused", "plan": plan_hash, "planner": planner, "who": who,
                     "reason": f"{action}: wrong passphrase", "at": time.time()},))
        self._refuse(f"{action} refused: {AUTH_REFUSED}")

    def _decidable(self, plan_hash: str, action: str, planner: str | None = None) -> tuple[PlanEntry, int, str]:
        """What every decision needs, checked before the passphrase (so no refusal tells it was right).

        The decision names the plan twice, by planner and by content hash: the hash is the one
        on the supervisor's screen, so a plan that changed since (a re-plan, another target)
        is refused instead of decided unseen; the planner keeps it unambiguous when two
        planners found the same sequence (one hash). The console page always names both; a
        caller of the Python API that names no planner gets the first of the current plans
        with that hash, and the decision records whose it is."""
        st = self._state
        if self._capturing:
            self._refuse(f"{action} refused: a capture is running")
        if st.planning:
            self._refuse(f"{action} refused: planning is still running")
        name, entry = self._named_plan(st, plan_hash, action, planner)
        if st.session_id is None:
            self._refuse(f"{action} refused: this capture has no session record ({st.audit or 'database'}); "
                         f"capture again once the database can be written")
        if (st.session_id, plan_hash) not in self._recorded:
            self._refuse(f"{action} refused: plan {plan_hash} was not recorded ({st.audit or 'database'}); "
                         f"plan again once the database can be written")
        return entry, st.session_id, name

    def _named_plan(self, st: State, plan_hash: str, action: str, planner: str | None) -> tuple[str, PlanEntry]:
        """(planner, entry) of the current capture's plan that is exactly (planner, plan_hash)."""
        if planner is not None:
            planner = str(planner)[:40]
            entry = st.plans.get(planner)
            if entry is not None and entry.hash == plan_hash:
                return planner, entry
            now = (f"it is now plan {entry.hash}" if entry is not None
                   else "there is no such plan for the current capture now")
            self._refuse(f"{action} refused: the {planner} plan changed since it was shown ({plan_hash} was "
                         f"reviewed, {now}); review the plan on the screen and decide again")
        named = [(n, e) for n, e in st.plans.items() if e.hash == plan_hash]
        if not named:
            self._refuse(f"{action} refused: plan {plan_hash} is not a plan for the current capture")
        return named[0]

    def approve(self, plan_hash: str, passphrase: str, who: str = "supervisor",
                accept_risk: bool = False, client: str = "local", planner: str | None = None) -> State:
        """Approve exactly this plan (planner + content hash) for exactly the current capture; takes the run lock.

        A plan predicted unsafe (the least risky one when no safe plan exists,
        or any plan on a shelf that does not stand as seen) needs
        `accept_risk`. The approval counts once its decision is committed; of
        two supervisors approving at once exactly one gets it.
        """
        who = (who or "supervisor")[:80]
        with self._lock:
            entry, sid, name = self._decidable(plan_hash, "approval", planner)
            if self._state.needs_recapture:
                self._refuse("approval refused: the shelf has changed, capture and plan again")
            self._held("approval")
            self._run_elsewhere("approval")   # one run at a time per database (console/workflow/run.py)
            risk_note = self._risk_note(entry, accept_risk)
        self._authenticate(plan_hash, passphrase, who, "approval", client, name)
        with self._lock:   # the state may have moved while the passphrase was checked
            entry, sid, name = self._decidable(plan_hash, "approval", name)
            self._held("approval")
            run = self._run = RunLock(plan_hash, entry, sid, self._generation, who, planner=name)
            self._live_stops.add(run.stop)
        try:
            run.decision_id = self.store.add_decision(sid, plan_hash, "approve", who, risk_note)
        except Exception as exc:  # noqa: BLE001 - audit first: an unrecorded approval is no approval
            with self._lock:
                self._release(run)
            msg = self._audit_failed("the approval", exc)
            self._refuse(f"approval refused: the decision could not be recorded, nothing will run ({msg})")
        with self._lock:
            if self._run is not run:     # Stop withdrew it while it was being recorded
                self._refuse("approval withdrawn: `Stop robot` was pressed while it was being recorded")
            dec = {"decision": "approve", "plan": plan_hash, "planner": name,
                   "who": who, "reason": risk_note, "at": time.time()}
            approval = {"plan": plan_hash, "planner": name, "session": sid, "capture": self._state.frame_name,
                        "who": who, "decision": run.decision_id}
            return self._set(approved=plan_hash, approval=approval, decisions=self._state.decisions + (dec,),
                             error=None, message=f"{who} approved the {name} plan {plan_hash}")

    def _risk_note(self, entry: PlanEntry, accept_risk: bool) -> str | None:
        cont = (entry.plan.extra or {}).get("continues")
        if isinstance(cont, Mapping):
            # the shelf already did not do what this plan predicted: continuing is a risk taken knowingly
            what = (f"continue plan {cont.get('plan')} as planned after a deviation at step "
                    f"{int(cont.get('after_step', 0)) + 1} (session {cont.get('session')})")
            if not accept_risk:
                self._refuse(f"approval refused: to {what}, tick 'Accept predicted risk' (the shelf "
                             f"differs from the prediction); or plan again from the new capture")
            return f"accepted: {what}"
        if entry.plan.safe:
            return None
        risk = f"{100 * entry.plan.risk:.0f}%"
        why = (f"the shelf does not stand as seen ({len(entry.scene_problems)} problem(s))"
               if entry.scene_problems else f"collapse risk up to {risk}")
        if not accept_risk:
            self._refuse(f"approval refused: the {entry.plan.planner} plan is predicted unsafe "
                         f"({why}); tick 'Accept predicted risk' to approve it anyway")
        return f"accepted predicted risk {risk}" + (
            f"; scene problems: {'; '.join(problem_text(p) for p in entry.scene_problems)}"
            if entry.scene_problems else "")
    def reject(self, plan_hash: str, passphrase: str, who: str = "supervisor", reason: str = "",
               client: str = "local", planner: str | None = None) -> State:
        """Reject a plan (planner + hash, as approve); rejecting the approved plan before it runs withdraws
        the approval."""
        if not (reason or "").strip():
            self._refuse("reject needs a reason")
        who, reason = (who or "supervisor")[:80], reason.strip()[:500]
        with self._lock:
            entry, sid, name = self._decidable(plan_hash, "rejection", planner)
            if self._run is not None and self._run.started:
                self._refuse("rejection refused: the robot is running; press `Stop robot`")
        self._authenticate(plan_hash, passphrase, who, "rejection", client, name)
        with self._lock:
            run = self._run
            if run is not None and run.plan_hash == plan_hash and not run.started:
                self._release(run)
            elif run is not None and run.started:
                self._refuse("rejection refused: the robot is running; press `Stop robot`")
            dec = {"decision": "reject", "plan": plan_hash, "planner": name,
                   "who": who, "reason": reason, "at": time.time()}
            approved = None if self._state.approved == plan_hash else self._state.approved
            self._set(approved=approved, approval=None if approved is None else self._state.approval,
                      decisions=self._state.decisions + (dec,), error=None,
                      message=f"{who} rejected the {name} plan: {reason}")
        self._record("the rejection", self.store.add_decision, sid, plan_hash, "reject", who, reason)
        return self.state


__all__ = ["Supervision"]
