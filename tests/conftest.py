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


@pytest.fixture()
def contradictory():
    """A perceived shelf with two faces no sample world can hold (planning/set_aside.py): `f` and
    `k` 5 cm apart in depth, one right behind the other (the camera cannot have seen `k`); `n`
    stands beside `f`, `c` stands alone 20 cm away. Depths are placeholders, as perceive writes."""
    from shelfpick.perception.scene import Box, Scene, Shelf

    def seen(bid, size, centre):
        return Box(bid, size, centre, (1.0, 0.0, 0.0, 0.0), None, False, None, {"perceived": {"distance": 1.0}})

    return Scene(Shelf(), (seen("f", (0.3, 0.25, 0.3), (0.2, 0.125, 0.15)),
                           seen("k", (0.3, 0.25, 0.3), (0.2, 0.175, 0.15)),
                           seen("n", (0.2, 0.25, 0.2), (-0.06, 0.125, 0.1)),
                           seen("c", (0.2, 0.25, 0.2), (-0.35, 0.125, 0.1))))
