"""Faces perception doubts in the console: a "?" on the box in the 3D view (a real viser server),
and the plan table's row saying which steps touch one (planning/contradicted.py)."""
from __future__ import annotations


def test_a_doubted_box_is_labelled_with_a_question_mark_and_the_others_by_id(server):
    from shelfpick.console.web.scene_view import draw_boxes
    from shelfpick.perception.scene import Box, Scene, Shelf

    doubted = Box("b1", (0.2, 0.2, 0.2), (0.1, 0.12, 0.1), extra={"perceived": {"contradicted": True}})
    plain = Box("b0", (0.2, 0.2, 0.2), (-0.2, 0.12, 0.1), extra={"perceived": {"contradicted": False}})
    nodes = draw_boxes(server.scene, Scene(Shelf(), (plain, doubted)))
    assert nodes["b1"].label.text == "b1 ?" and nodes["b0"].label.text == "b0"


def test_the_plan_table_says_what_touches_a_doubted_face_and_escapes_it():
    from shelfpick.console.web.markdown import results_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State
    from shelfpick.planning.plan import Plan, StepPrediction

    why = "step 1: pulling b_0 touches b*1, a box whose perceived face cannot be right as seen"
    touched = Plan("extract", "b_0", "physics", ("b_0",), (StepPrediction("b_0"),), False, {}, 0,
                   {"contradicted": {"boxes": ["b*1"], "touched": [why]}})
    clear = Plan("extract", "b_0", "heuristic", ("b_0",), (StepPrediction("b_0"),), True, {}, 0,
                 {"contradicted": {"boxes": ["b*1"], "touched": []}})
    plans = {"physics": PlanEntry(touched, touched.content_hash()), "heuristic": PlanEntry(clear, clear.content_hash())}
    md = results_markdown(State(plans=plans))
    row = next(ln for ln in md.splitlines() if ln.startswith("| faces that cannot all be right |"))
    assert "pulling b&#95;0 touches b&#42;1" in row and "not touched" in row   # outside text, escaped
    plain = Plan("extract", "b0", "physics", ("b0",), (StepPrediction("b0"),), True, {}, 0, {})
    assert "cannot all be right" not in results_markdown(State(plans={"physics": PlanEntry(plain, plain.content_hash())}))


def test_the_status_shows_every_perception_warning_not_only_the_first_three():
    """The "cannot all be right" warnings that mark boxes "?" came after the unexplained matter, a
    mask cut in two and a box at the image border on the demo shelf demo-unstructured-6, and the
    status showed the first three only: the reason the plans were not safe was not on the page."""
    from shelfpick.console.web.markdown import status_markdown
    from shelfpick.console.workflow.machine import State

    said = ("2 regions of matter inside the shelf that no perceived box explains", "mask 1 is 2 fronts",
            "b7 touches the top image border", "b2: pushed up 15.7 cm out of b1; their perceived faces cannot all be right",
            "b5: pushed up 13.6 cm out of b2; their perceived faces cannot all be right")
    md = status_markdown(State(warnings=said))
    lines = [ln for ln in md.split("\n\n") if ln.startswith("_perception: ")]
    assert len(lines) == 5
    assert "b5&#58; pushed up 13&#46;6 cm out of b2" in lines[-1]     # escaped, as all text from perception


def test_the_supervisor_reads_why_a_plan_is_not_safe_before_accepting_its_risk():
    """The pending plans and the plan under review say why it is not safe: the calibrated chance
    against the threshold, and what it touches that perception doubts; outside text escaped."""
    from shelfpick.console.web.panels import review_markdown, supervisor_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State
    from shelfpick.planning.plan import Plan, StepPrediction

    why = "step 1: pulling b_0 touches b*1, a box whose perceived face cannot be right as seen"
    risk = {"probability": 0.09, "low": 0.03, "high": 0.21, "max_plan_risk": 0.05, "failed_worlds": 3, "worlds": 20}
    risky = Plan("extract", "b_0", "physics", ("b_0",), (StepPrediction("b_0"),), False, {}, 0,
                 {"contradicted": {"boxes": ["b*1"], "touched": [why]}, "search": {"plan_risk": risk}})
    safe = Plan("extract", "b_0", "heuristic", ("b_0",), (StepPrediction("b_0"),), True, {}, 0,
                {"search": {"plan_risk": {**risk, "high": 0.03}}})
    entry = PlanEntry(risky, risky.content_hash())
    text = supervisor_markdown(State(plans={"physics": entry, "heuristic": PlanEntry(safe, safe.content_hash())}))
    assert "up to 21.0%, not below the threshold 5.0%" in text
    assert "pulling b&#95;0 touches b&#42;1" in text and "b_0 touches" not in text
    assert text.count("threshold") == 1          # the safe plan gives no reason
    assert "up to 21.0%" in review_markdown("physics", entry) and "b&#42;1" in review_markdown("physics", entry)


def test_a_safe_plan_whose_step_collides_says_both_numbers():
    """31011 (labels): a plan declared safe (1 of 10 worlds collapsed: 0.95%, up to 2.8%) whose
    second step knocked a neighbour in 5 of 10 worlds read "max risk 50%" beside "safe": the
    supervisor now reads the chance "safe" is decided on and, apart, what the worst step does."""
    from shelfpick.console.web.panels import review_markdown, supervisor_markdown
    from shelfpick.console.workflow.machine import PlanEntry, State
    from shelfpick.planning.plan import Plan, StepPrediction

    risk = {"probability": 0.0095, "low": 0.0086, "high": 0.028, "max_plan_risk": 0.05, "failed_worlds": 1,
            "worlds": 10}
    plan = Plan("extract", "b9", "physics", ("b11", "b9"),
                (StepPrediction("b11"), StepPrediction("b9", 0.1, 0.5, ("b12", "b8"))), True, {}, 0,
                {"search": {"plan_risk": risk}})
    entry = PlanEntry(plan, plan.content_hash())
    words = "chance of a collapse 0.9%, up to 2.8%; worst step collapses or collides in 50% of sample worlds"
    assert words in review_markdown("physics", entry)
    assert words in supervisor_markdown(State(plans={"physics": entry}))
    assert "max risk" not in review_markdown("physics", entry)
    bare = Plan("extract", "b9", "heuristic", ("b9",), (StepPrediction("b9", 0.2, 0.0),), False, {}, 0, {})
    assert "(worst step collapses or collides in 20% of sample worlds, predicted UNSAFE)" in \
        review_markdown("heuristic", PlanEntry(bare, bare.content_hash()))
