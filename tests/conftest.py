"""Shared test set-up: ultralytics stays offline, plots render headless."""
from __future__ import annotations

import json
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


# the lines printed at the end of a run that injected any fault, by tally (tests/console/safety_kit.py)
LINES = {
    "TALLY": "console fault injection: {faults} faults injected, {unapproved} robot steps ran unapproved, "
             "{unrecorded} unrecorded, {stops} stops of which {stops_not_stopping} did not stop",
    "ROBOT_TALLY": "robot fault injection: {faults} faults injected, {unapproved} steps sent after a fault, "
                   "{unrecorded} steps unrecorded, {stops} stops of which {stops_not_stopping} did not stop",
}
_FROM_WORKERS: list[dict[str, dict[str, int]]] = []    # the tallies pytest-xdist's workers handed back


def _own_tallies() -> dict[str, dict[str, int]]:
    """This process's fault tallies (tests/console/safety_kit.py), by name; none if no test used it."""
    import sys

    kit = sys.modules.get("safety_kit")
    return {} if kit is None else {name: dict(getattr(kit, name)) for name in LINES}


def pytest_sessionfinish(session) -> None:
    """A pytest-xdist worker hands its tallies to the controller, which prints them."""
    out = getattr(session.config, "workeroutput", None)
    if out is not None:
        out["safety_tallies"] = json.dumps(_own_tallies())


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error) -> None:
    got = getattr(node, "workeroutput", {}).get("safety_tallies")
    if got:
        _FROM_WORKERS.append(json.loads(got))


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    """Print the safety tallies (tests/console/safety_kit.py) at the end of a run that injected any
    fault: faults injected, unapproved/unrecorded steps, stops that did not stop; summed over the
    workers when the run is spread over processes (`make test` runs two).
    (Here, not in tests/console/conftest.py: two conftest modules shadow each other's imports.)"""
    total: dict[str, dict[str, int]] = {}
    for part in [_own_tallies(), *_FROM_WORKERS]:
        for name, tally in part.items():
            into = total.setdefault(name, dict.fromkeys(tally, 0))
            for k, v in tally.items():
                into[k] += v
    for name, tally in total.items():
        if tally["faults"]:
            terminalreporter.write_line(LINES[name].format(**tally))


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
