"""C output kept off stdout without losing what other threads print (a real subprocess: file
descriptors belong to the whole process)."""
from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

CHILD = textwrap.dedent("""
    import sys, threading
    sys.path.insert(0, {root!r})
    from contextlib import nullcontext
    from shelfpick.perception.stdio import c_output_detached
    from shelfpick.planning.bullet_clients import connect, disconnect_quietly

    def connects(n):
        for _ in range(n):
            disconnect_quietly(connect())

    with (c_output_detached() if {detached} else nullcontext()):
        threads = [threading.Thread(target=connects, args=(40,)) for _ in range(3)]
        for t in threads:
            t.start()
        if {detached}:
            for i in range(300):                 # printed while the others connect
                print("line", i, flush=True)
        for t in threads:
            t.join()
        print("after", flush=True)
""")


def run_child(detached: bool) -> list[str]:
    code = CHILD.format(root=str(ROOT), detached=detached)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert out.returncode == 0, out.stderr
    return out.stdout.splitlines()


def test_detached_stdout_keeps_every_line_while_threads_connect():
    lines = run_child(True)
    assert lines == [f"line {i}" for i in range(300)] + ["after"]     # none lost, no "argv[0]="


def test_overlapping_redirections_from_threads_leave_stdout_where_it_was():
    assert run_child(False) == ["after"]        # fd 1 put back, and no C banner on it
