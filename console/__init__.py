"""shelfpick's console: the operator and supervisor web app, the robot drivers and the session store.

The public API is listed in `__all__`; the names are imported when first used (PEP 562), so
that `shelfpick --help` does not load viser, numpy or the physics engine.
See docs/ARCHITECTURE.md for the module map and the flow from a capture to a robot step.
"""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "main": "console.cli",                                   # the `shelfpick` command line
    "ConsoleApp": "console.app",                             # the viser server and its client views
    "Workflow": "console.workflow",                          # capture -> plans -> approval -> robot run
    "SessionStore": "console.store",                         # the SQLite record of every session
    "open_robot": "console.robot", "SimRobot": "console.robot", "TcpRobot": "console.robot_tcp",
    "open_source": "console.sources",                        # demo, files or RealSense captures
    "read_cell": "console.cell", "Cell": "console.cell",     # a robot cell's configuration file
    "compare": "console.verify", "Tolerance": "console.verify",  # predicted vs observed after a step
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'console' has no attribute {name!r}")
