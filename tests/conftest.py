"""Shared test set-up: ultralytics stays offline, plots render headless."""
from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
os.environ.setdefault("YOLO_OFFLINE", "1")
os.environ.setdefault("YOLO_AUTOINSTALL", "0")
os.environ.setdefault("YOLO_VERBOSE", "0")
os.environ.setdefault("YOLO_CONFIG_DIR", str(ROOT / ".yolo"))
os.environ.setdefault("MPLBACKEND", "Agg")

REALDATA = ROOT.parent / "shared" / "realdata"


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """Print the console's safety tally (tests/console/safety_kit.py) at the end of a run that
    injected any fault: faults injected, unapproved/unrecorded steps, stops that did not stop.
    (Here, not in tests/console/conftest.py: two conftest modules shadow each other's imports.)"""
    import sys

    kit = sys.modules.get("safety_kit")
    if kit is not None and kit.TALLY["faults"]:
        terminalreporter.write_line(
            "console fault injection: {faults} faults injected, {unapproved} robot steps ran unapproved, "
            "{unrecorded} unrecorded, {stops} stops of which {stops_not_stopping} did not stop".format(**kit.TALLY))


@pytest.fixture()
def server():
    """A real viser server on a free local port, stopped after the test (the console's views)."""
    import viser

    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        yield s
    finally:
        s.stop()
