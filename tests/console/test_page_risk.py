"""The plan table shows the calibrated chance of a collapse, its upper end and the plan threshold
(issue 32), and nothing where a plan carries no gate (a stored plan from before)."""
from __future__ import annotations

from shelfpick.planning.plan import Plan, StepPrediction


def _rows(md: str) -> dict[str, list[str]]:
    return {ln.split("|")[1].strip(): [c.strip() for c in ln.split("|")[2:-1]]
            for ln in md.splitlines()[2:] if ln.startswith("|")}


def test_the_table_shows_the_calibrated_risk_and_the_threshold():
    from shelfpick.console.web.markdown import results_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State

    gated = Plan("extract", "b0", "physics", ("b1", "b0"), (StepPrediction("b1"), StepPrediction("b0")), True,
                 {"planning_s": 1.0}, 0, {"search": {"worlds": 10, "verified_worlds": 20, "max_plan_risk": 0.05,
                                                     "plan_risk": {"probability": 0.0123, "low": 0.004, "high": 0.031,
                                                                   "failed_worlds": 0, "worlds": 20,
                                                                   "max_plan_risk": 0.05}}})
    old = Plan("extract", "b0", "heuristic", ("b0",), (StepPrediction("b0", 0.5),), False, {"planning_s": 0.1}, 0)
    md = results_markdown(State(plans={"physics": PlanEntry(gated, gated.content_hash()),
                                       "heuristic": PlanEntry(old, old.content_hash())}))
    row = _rows(md)["chance of a collapse (calibrated)"]
    assert row == ["1.2% (up to 3.1%; threshold 5.0%); failed in 0 of 20 sample worlds", "—"]
    # the gate's 20 worlds came after the search's 10: not "10 searched, 10 more"
    assert _rows(md)["sample worlds behind the risks"] == ["20 (fresh: asked after the 10 the search chose the plan in)",
                                                           "—"]


def test_the_table_shows_worlds_that_failed_behind_a_safe_verdict():
    """A plan the map calls safe although some of the gate's worlds collapsed says how many (the
    lifting map puts up to 2 of 10 and 4 of 20 on its floor: docs/results/risk-gate.md)."""
    from shelfpick.console.web.markdown import results_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State

    def plan(gate: dict) -> Plan:
        return Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0", 0.15),), True, {"planning_s": 1.0}, 0,
                    {"search": {"worlds": 10, "verified_worlds": 20, "max_plan_risk": 0.05, "plan_risk": gate}})

    risk = {"probability": 0.0086, "low": 0.0086, "high": 0.028, "max_plan_risk": 0.05}
    shown = plan({**risk, "failed_worlds": 3, "worlds": 20})
    odd = plan({**risk, "failed_worlds": 30, "worlds": 20})       # a count that cannot be: not shown
    md = results_markdown(State(plans={"physics": PlanEntry(shown, shown.content_hash()),
                                       "heuristic": PlanEntry(odd, odd.content_hash())}))
    assert _rows(md)["chance of a collapse (calibrated)"] == [
        "0.9% (up to 2.8%; threshold 5.0%); failed in 3 of 20 sample worlds", "0.9% (up to 2.8%; threshold 5.0%)"]


def test_the_baselines_gated_worlds_do_not_claim_a_search_chose_it():
    """Highest-first chooses its order in no world; the gate's fresh worlds came after the ten its
    steps were first predicted in (seen in Chromium: both columns said the search chose the plan)."""
    from shelfpick.console.web.markdown import results_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State

    gate = {"probability": 0.0086, "low": 0.0086, "high": 0.028, "failed_worlds": 0, "worlds": 10,
            "max_plan_risk": 0.05}
    plans = {name: Plan("extract", "b0", name, ("b0",), (StepPrediction("b0"),), True, {"planning_s": 1.0}, 0,
                        {"search": {"worlds": 10, "verified_worlds": 10, "max_plan_risk": 0.05, "plan_risk": gate}})
             for name in ("physics", "heuristic")}
    md = results_markdown(State(plans={k: PlanEntry(p, p.content_hash()) for k, p in plans.items()}))
    assert _rows(md)["sample worlds behind the risks"] == [
        "10 (fresh: asked after the 10 the search chose the plan in)",
        "10 (fresh: asked after the 10 its steps were first predicted in)"]
