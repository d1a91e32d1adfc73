"""Console tests: print the safety tally (faults injected, unapproved/unrecorded steps, stops that
did not stop) at the end of a run that injected any."""
from __future__ import annotations


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:
    try:
        from safety_kit import TALLY
    except ImportError:
        return
    if TALLY["faults"]:
        terminalreporter.write_line(
            "console fault injection: {faults} faults injected, {unapproved} robot steps ran unapproved, "
            "{unrecorded} unrecorded, {stops} stops of which {stops_not_stopping} did not stop".format(**TALLY))
