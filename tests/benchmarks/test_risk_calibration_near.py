"""benchmarks/risk_calibration.py near: a plan's worlds are its steps' worlds together."""
from benchmarks.risk_calibration import near_plans


def _step(target: str, step: int, c: list[int], m: list[float], ok: bool) -> dict:
    return {"scene": "s", "noise": 0.0, "source": "plan", "target": target, "step": step,
            "c": c, "s": [0] * len(c), "m": m, "plan_ok": ok}


def test_a_plans_world_fails_when_any_step_does_and_is_as_near_as_its_nearest_step():
    rows = [_step("b1", 0, [0, 0, 1], [0.2, 0.9, 3.0], False), _step("b1", 1, [0, 1, 0], [0.5, 2.0, 0.1], False),
            {"scene": "s", "noise": 0.0, "source": "alone", "box": "b2", "c": [0, 0], "s": [0, 1],
             "m": [0.3, 0.0], "collapse": False, "extracted": True}]
    by = {len(p["fails"]): p for p in near_plans(rows)}
    assert by[3] == {"fails": [0, 1, 1], "near": [0.5, 1.0, 1.0], "failed": True}
    assert by[2] == {"fails": [0, 1], "near": [0.3, 1.0], "failed": False}
