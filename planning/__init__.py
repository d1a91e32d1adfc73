"""shelfpick's planning: predict what pulling a box does to the shelf, and plan the picks.

The public API is listed in `__all__`; the names are imported when first used (PEP 562), so
that `import planning.cmd_plan` for a CLI's ``--help`` does not load the physics engine.
See docs/ARCHITECTURE.md for the module map.
"""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "make_plan": "shelfpick.planning.planner", "PLANNERS": "shelfpick.planning.plan",
    "Plan": "shelfpick.planning.plan", "StepPrediction": "shelfpick.planning.plan",
    "PhysicsConfig": "shelfpick.planning.physics",
    "Uncertainty": "shelfpick.planning.uncertainty",
    "Predictor": "shelfpick.planning.predict",
    "Predicting": "shelfpick.planning.oracle", "Screening": "shelfpick.planning.oracle",
    "ShelfSim": "shelfpick.planning.sim", "StepResult": "shelfpick.planning.step_result",
    "ClientPool": "shelfpick.planning.bullet_clients", "WorkerPool": "shelfpick.planning.worker_pool",
    "execute_plan": "shelfpick.planning.execute", "Execution": "shelfpick.planning.execute",
    "generate": "shelfpick.planning.shelves",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'planning' has no attribute {name!r}")
