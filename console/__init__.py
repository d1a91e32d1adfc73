"""shelfpick's console: the operator and supervisor web app, the robot drivers and the session store.

The public API is listed in `__all__`; the names are imported when first used (PEP 562), so
that `shelfpick --help` does not load viser, numpy or the physics engine.
The rooms: `robot/` (the drivers), `store/` (the session log), `workflow/` (the state machine),
`web/` (the viser page); the commands, the cell file and the capture sources sit here.
See docs/ARCHITECTURE.md for the module map and the flow from a capture to a robot step.
"""
from __future__ import annotations

import importlib
from typing import Any

_WHERE = {
    "main": "shelfpick.console.cli",                            # the `shelfpick` command line
    "ConsoleApp": "shelfpick.console.web.app",                  # the viser server and its client views
    "Workflow": "shelfpick.console.workflow.machine",           # capture -> plans -> approval -> robot run
    "SessionStore": "shelfpick.console.store.sessions",         # the SQLite record of every session
    "open_robot": "shelfpick.console.robot.drivers", "SimRobot": "shelfpick.console.robot.drivers",
    "TcpRobot": "shelfpick.console.robot.tcp",                  # the robot drivers
    "open_source": "shelfpick.console.sources",                 # demo, files or RealSense captures
    "read_cell": "shelfpick.console.cell", "Cell": "shelfpick.console.cell",  # a robot cell's configuration file
    "compare": "shelfpick.console.workflow.verify",             # predicted vs observed after a step
    "Tolerance": "shelfpick.console.workflow.verify",
}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        return getattr(importlib.import_module(_WHERE[name]), name)
    raise AttributeError(f"module 'console' has no attribute {name!r}")
