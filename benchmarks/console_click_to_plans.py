"""Click-to-plans on the 6-box demo shelf: `Plan extraction` / `Plan clearance` to both plans shown.

A `Workflow` as `make run` builds it (demo:demo-small-6, 10 depth samples, the sim robot, a real
SQLite file) captures once per demo seed; each capture is planned cold (sample worlds built) for
extraction of its last box, then for clearance (worlds kept). "Plans shown": from the click
(`Workflow.plan`) to both plans with their previews recorded and in the state the page draws;
"collapse worlds": how much later the worlds a risky step is shown in arrive (the preview only).

    .venv/bin/python benchmarks/console_click_to_plans.py --captures 3 --workers 2
"""
from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--captures", type=int, default=3, help="demo captures (demo seeds 0..N-1)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--shelf", default="demo-small-6", help="demo shelf (static/demo/NAME.json)")
    args = ap.parse_args()
    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.sources import open_source
    from shelfpick.console.store.sessions import SessionStore
    from shelfpick.console.workflow.machine import Workflow

    rows: dict[str, list[float]] = {"extract (cold)": [], "clear (worlds kept)": []}
    worlds: dict[str, list[float]] = {k: [] for k in rows}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.captures):
            store = SessionStore(Path(tmp) / f"s{seed}.sqlite")
            wf = Workflow(open_source(f"demo:{args.shelf}", seed=seed), store,
                          lambda t, s: open_robot("sim", truth=t, seed=s), "benchmark-passphrase",
                          samples=10, seed=0, workers=args.workers)
            try:
                wf.capture()
                for name, task in (("extract (cold)", "extract"), ("clear (worlds kept)", "clear")):
                    t0 = time.perf_counter()
                    wf.plan(task)
                    while wf.state.planning:          # the plans are on the page once planning is over
                        time.sleep(0.005)
                    dt = time.perf_counter() - t0
                    st = wf.wait_planning()           # then the worlds a risky step is shown in
                    dw = time.perf_counter() - t0
                    assert st.plans, st.error
                    rows[name].append(dt)
                    worlds[name].append(dw - dt)
                    risky = sum(1 for e in st.plans.values() for p in e.plan.predicted if p.collapse_prob > 0)
                    print(f"seed {seed} {name}: plans shown {dt:.2f} s, collapse worlds {dw - dt:.2f} s later "
                          f"({len(st.scene.boxes)} boxes, {risky} risky steps over both plans)", flush=True)
            finally:
                wf.close()
                store.close()
    for name, ts in rows.items():
        print(f"{name}: plans shown median {statistics.median(ts):.2f} s, max {max(ts):.2f} s over {len(ts)} "
              f"captures; collapse worlds after them median {statistics.median(worlds[name]):.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
