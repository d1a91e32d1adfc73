"""shelfpick's console: the operator and supervisor web app, the robot drivers and the session store.

The public API is listed in `__all__`; the names are imported when first used (PEP 562), so
that `shelfpick --help` does not load viser, numpy or the physics engine.
See docs/ARCHITECTURE.md for the module map and the flow from a capture to a robot step.
"""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "main": "shelfpick.console.cli",                                   # the `shelfpick` command line
    "ConsoleApp": "shelfpick.console.app",                             # the viser server and its client views
    "Workflow": "shelfpick.console.workflow",                          # capture -> plans -> approval -> robot run
    "SessionStore": "shelfpick.console.store",                         # the SQLite record of every session
    "open_robot": "shelfpick.console.robot", "SimRobot": "shelfpick.console.robot", "TcpRobot": "shelfpick.console.robot_tcp",
    "open_source": "shelfpick.console.sources",                        # demo, files or RealSense captures
    "read_cell": "shelfpick.console.cell", "Cell": "shelfpick.console.cell",     # a robot cell's configuration file
    "compare": "shelfpick.console.verify", "Tolerance": "shelfpick.console.verify",  # predicted vs observed after a step
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'console' has no attribute {name!r}")
