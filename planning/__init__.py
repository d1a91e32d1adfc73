"""shelfpick's planning: predict what pulling a box does to the shelf, and plan the picks.

The public API is listed in `__all__`; the names are imported when first used (PEP 562), so
that `import planning.cmd_plan` for a CLI's ``--help`` does not load the physics engine.
See docs/ARCHITECTURE.md for the module map.
"""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "make_plan": "planning.planner", "PLANNERS": "planning.plan",
    "Plan": "planning.plan", "StepPrediction": "planning.plan",
    "PhysicsConfig": "planning.physics",
    "Uncertainty": "planning.uncertainty",
    "Predictor": "planning.predict",
    "Predicting": "planning.oracle", "Screening": "planning.oracle",
    "ShelfSim": "planning.sim", "StepResult": "planning.step_result",
    "ClientPool": "planning.bullet_clients", "WorkerPool": "planning.worker_pool",
    "execute_plan": "planning.execute", "Execution": "planning.execute",
    "generate": "planning.shelves",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'planning' has no attribute {name!r}")
