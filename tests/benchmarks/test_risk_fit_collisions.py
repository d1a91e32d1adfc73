"""benchmarks/risk_fit.py: with `collisions` a world fails also where a neighbour was knocked."""
from benchmarks.risk_fit import plans


def _row(target: str, step: int, c: list[int], x: list[int]) -> dict:
    return {"scene": "structured-11", "noise": 0.0, "kind": "structured", "source": "plan", "target": target,
            "step": step, "c": c, "s": [0] * len(c), "x": x, "stands": True, "plan_ok": True}


def test_collisions_count_only_when_asked():
    rows = [_row("b1", 0, [0, 0, 0], [1, 0, 0]), _row("b1", 1, [0, 1, 0], [0, 0, 1])]
    assert plans(rows)[0]["fails"] == [0, 1, 0]
    assert plans(rows, collisions=True)[0]["fails"] == [1, 1, 1]
