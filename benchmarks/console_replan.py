"""The console's wait for a plan: later targets of one capture against the same targets planned cold.

A `Workflow` (the console's, real SQLite file, demo source) captures once and plans extraction of
`--targets` boxes one after the other: the first builds the sample worlds, the later ones reuse
them (console/workflow/planning_stage.py). Each target is also planned by a fresh workflow from the same
capture (what every plan cost before worlds were kept: worlds built, worker processes started).
The sequences must agree; the times are `Workflow.plan` wall times.

    .venv/bin/python benchmarks/console_replan.py --captures 3 --targets 4 --workers 2
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def _workflow(db: Path, workers: int, seed: int):
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.sources import open_source
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    store = SessionStore(db)
    wf = Workflow(open_source("demo", seed=seed), store, lambda t, s: open_robot("sim", truth=t, seed=s),
                  "benchmark-passphrase", samples=10, seed=0, workers=workers)
    return wf, store


def _timed_plan(wf, target: str) -> tuple[float, tuple]:
    wf.select_target(target)
    t0 = time.perf_counter()
    st = wf.plan("extract", wait=True)
    return time.perf_counter() - t0, tuple(st.plans[p].plan.sequence for p in sorted(st.plans))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=int, default=3, help="demo captures (demo seeds 0..N-1)")
    ap.add_argument("--targets", type=int, default=4, help="targets planned per capture")
    ap.add_argument("--workers", type=int, default=2)
    args = ap.parse_args(argv)
    later, cold, first = [], [], []
    with tempfile.TemporaryDirectory(prefix="shelfpick-replan-") as tmp:
        for c in range(args.captures):
            wf, store = _workflow(Path(tmp) / f"kept{c}.sqlite", args.workers, c)
            ids = wf.capture().scene.ids[: args.targets]
            for i, target in enumerate(ids):
                dt, seqs = _timed_plan(wf, target)
                (first if i == 0 else later).append(dt)
                fresh, fstore = _workflow(Path(tmp) / f"cold{c}-{i}.sqlite", args.workers, c)
                fresh.capture()
                dt_cold, seqs_cold = _timed_plan(fresh, target)
                fresh.close()
                fstore.close()
                if i:
                    cold.append(dt_cold)
                if seqs != seqs_cold:
                    print(f"capture {c} target {target}: plans differ {seqs} vs {seqs_cold}", file=sys.stderr)
                    return 1
                print(f"capture {c} target {target}: {'first' if i == 0 else 'kept '} {dt:.2f} s, "
                      f"cold {dt_cold:.2f} s, same plans", flush=True)
            wf.close()
            store.close()
    med = statistics.median
    print(f"{args.captures} captures x {args.targets} targets, workers {args.workers}: first plan of a capture "
          f"median {med(first):.2f} s; later targets median {med(later):.2f} s (max {max(later):.2f}) "
          f"against {med(cold):.2f} s (max {max(cold):.2f}) planned cold; every plan the same")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
