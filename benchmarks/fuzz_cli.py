"""Run the second bad-input corpus (tests/fuzz_corpus/make_fuzz.py) through the real `shelfpick`
command, one subprocess a case, and count: every case must exit 2 with exactly one stderr line
saying what it should, no traceback, within 10 s and under 1 GB of peak memory (the child's
ru_maxrss from wait4; an address-space limit of 4 GB keeps a runaway case from taking the machine).

    python benchmarks/fuzz_cli.py                  # all cases, counts by kind, failures listed
    python benchmarks/fuzz_cli.py --only url- db-  # the cases whose names start so
    python benchmarks/fuzz_cli.py --json out.json  # every case's result as well

Exit 0 when every case passed, 1 otherwise. One case at a time (the machine is shared).
"""
from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "tests" / "fuzz_corpus"))
import make_fuzz  # noqa: E402

SECONDS = 10.0
MAX_RSS = 1 << 30            # bytes
ADDRESS_LIMIT = 4 << 30      # a safety net only; the verdict is on ru_maxrss


@dataclass(frozen=True)
class Result:
    name: str
    rc: int | None             # None: killed after SECONDS
    lines: int
    line: str
    seconds: float
    max_rss: int               # bytes
    problems: tuple[str, ...]  # empty: the case passed


def judge(case: make_fuzz.FuzzCase, rc: int | None, err: str, seconds: float, rss: int) -> tuple[str, ...]:
    """What is wrong with one run (empty: a one-line refusal, exit 2, in time and memory)."""
    lines = [ln for ln in err.splitlines() if ln.strip()]
    out = []
    if rc is None:
        out.append(f"hung: killed after {SECONDS:g} s")
    elif rc != 2:
        out.append(f"exit {rc}, not 2")
    if "Traceback" in err:
        out.append("traceback")
    if len(lines) != 1:
        out.append(f"{len(lines)} stderr lines, not 1")
    elif case.says not in lines[0]:
        out.append(f"the line does not say {case.says!r}")
    if seconds >= SECONDS:
        out.append(f"{seconds:.1f} s")
    if rss >= MAX_RSS:
        out.append(f"peak memory {rss / 2**20:.0f} MiB")
    return tuple(out)


# A small wrapper process sets the address-space limit, forks and execs the command, and writes the
# command's ru_maxrss to a file. Measured from this process directly, the child's peak would start
# at this process's own size: Linux carries the memory of the process that was replaced by exec into
# ru_maxrss, and a spawned child starts as a copy of (or shares) a parent that may be a large pytest run.
WRAP = """import os, resource, sys
resource.setrlimit(resource.RLIMIT_AS, ({0}, {0}))
pid = os.fork()
if pid == 0:
    os.execv(sys.executable, [sys.executable, "-m", "shelfpick.console.cli", *sys.argv[2:]])
_, status, usage = os.wait4(pid, 0)
with open(sys.argv[1], "w") as f:
    f.write(str(usage.ru_maxrss))
code = os.waitstatus_to_exitcode(status)
os._exit(code if code >= 0 else 128 - code)
""".format(ADDRESS_LIMIT)


def run_case(case: make_fuzz.FuzzCase, env: dict[str, str]) -> Result:
    """One subprocess: `python -m shelfpick.console.cli ARGV`, its exit, stderr, wall time and peak RSS."""
    with tempfile.TemporaryFile() as err_file, tempfile.TemporaryDirectory() as scratch:
        rss_file = Path(scratch) / "maxrss"
        t0 = time.monotonic()
        proc = subprocess.Popen([sys.executable, "-c", WRAP, str(rss_file), *case.argv], cwd=ROOT, env=env,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err_file,
                                start_new_session=True)   # its own group: a timeout kills all it started
        try:
            rc: int | None = proc.wait(timeout=SECONDS)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            rc = None
        seconds = time.monotonic() - t0
        err_file.seek(0)
        err = err_file.read().decode("utf-8", "replace")
        rss = int(rss_file.read_text() or 0) * 1024 if rss_file.exists() else 0   # Linux: KiB
    lines = [ln for ln in err.splitlines() if ln.strip()]
    return Result(case.name, rc, len(lines), lines[0][:300] if lines else "", round(seconds, 2), rss,
                  judge(case, rc, err, seconds, rss))


def child_env() -> dict[str, str]:
    env = dict(os.environ)
    env.update({"YOLO_OFFLINE": "1", "YOLO_AUTOINSTALL": "0", "YOLO_VERBOSE": "0", "MPLBACKEND": "Agg",
                "PYTHONPATH": str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")})
    return env


def run_all(tmp: Path, only: tuple[str, ...] = ()) -> list[Result]:
    cases = [c for c in make_fuzz.build(tmp) if not only or c.name.startswith(only)]
    env = child_env()
    return [run_case(c, env) for c in cases]


def summary(results: list[Result]) -> str:
    kinds: dict[str, list[Result]] = {}
    for r in results:
        kinds.setdefault(r.name.split("-")[0], []).append(r)
    rows = ["| kind | cases | passed | slowest s | peak MiB |", "|---|---|---|---|---|"]
    for kind, rs in kinds.items():
        rows.append(f"| {kind} | {len(rs)} | {sum(not r.problems for r in rs)} | {max(r.seconds for r in rs):.2f} | "
                    f"{max(r.max_rss for r in rs) / 2**20:.0f} |")
    ok = sum(not r.problems for r in results)
    rows.append(f"| all | {len(results)} | {ok} | {max((r.seconds for r in results), default=0):.2f} | "
                f"{max((r.max_rss for r in results), default=0) / 2**20:.0f} |")
    tally = {
        "exit 2 and one line": sum(r.rc == 2 and r.lines == 1 for r in results),
        "tracebacks": sum("traceback" in r.problems for r in results),
        "hung (killed at 10 s)": sum(r.rc is None for r in results),
        "over 1 GB": sum(r.max_rss >= MAX_RSS for r in results),
    }
    rows.append("")
    rows.append(", ".join(f"{k}: {v}" for k, v in tally.items()))
    for r in results:
        if r.problems:
            rows.append(f"FAILED {r.name}: {'; '.join(r.problems)} -- {r.line}")
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", nargs="*", default=[], help="run the cases whose names start with these")
    ap.add_argument("--json", default=None, help="write every case's result here")
    ap.add_argument("--keep", default=None, help="build the cases in this folder (default: a temporary one)")
    args = ap.parse_args(argv)
    t0 = time.monotonic()
    if args.keep:
        results = run_all(Path(args.keep), tuple(args.only))
    else:
        with tempfile.TemporaryDirectory(prefix="shelfpick-fuzz-") as tmp:
            results = run_all(Path(tmp), tuple(args.only))
    print(summary(results))
    print(f"\n{len(results)} cases in {time.monotonic() - t0:.0f} s")
    if args.json:
        Path(args.json).write_text(json.dumps([asdict(r) for r in results], indent=1) + "\n")
    return 0 if all(not r.problems for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
