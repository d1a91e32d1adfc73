"""The suite's safety tallies reach its report when it runs in several processes, as `make test`
runs it: each worker counts the faults it injected, the controller prints the sums
(tests/conftest.py). Without that the two lines CI readers look for would silently vanish."""
from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_the_fault_tallies_are_printed_when_the_suite_runs_in_two_processes():
    # two files, one to each worker (--dist loadfile): both lines come from workers, none from here
    out = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadfile", "-p", "no:cacheprovider",
         "tests/console/test_faults_robot.py", "tests/console/test_safety_workflow.py",
         "-k", "a_peer_that_disconnects or approve_and_execute_refused_while_a_capture_runs"],
        cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    assert re.search(r"^robot fault injection: [1-9]\d* faults injected, 0 steps sent after a fault, "
                     r"0 steps unrecorded", out.stdout, re.M), out.stdout[-3000:]
    assert re.search(r"^console fault injection: [1-9]\d* faults injected, 0 robot steps ran unapproved, "
                     r"0 unrecorded", out.stdout, re.M), out.stdout[-3000:]
