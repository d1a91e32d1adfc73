"""`shelfpick console`: start the operator console (viser web app) and print its URL."""
from __future__ import annotations

import argparse
import os
import secrets
from pathlib import Path

HELP = "start the operator console: capture, compare plans, approve, execute, replay (web app)"
ENV_PASSPHRASE = "SHELFPICK_SUPERVISOR_PASSPHRASE"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--source", default="demo",
                   help="demo | files:DIR | realsense | bag:FILE (default: demo, synthetic shelves)")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1; others need a supervisor passphrase)")
    p.add_argument("--port", type=int, default=8080, help="port (0 = any free port; default 8080)")
    p.add_argument("--db", default=None, help="session database (default ./data/shelfpick.db, as `shelfpick sessions`)")
    p.add_argument("--robot", default="sim", help="sim | tcp://HOST:PORT (default sim)")
    p.add_argument("--supervisor-passphrase", default=None,
                   help=f"passphrase for Approve/Reject (or env {ENV_PASSPHRASE}); at least 12 characters "
                        "on a non-local --host; generated and printed when unset on a local address")
    p.add_argument("--samples", type=int, default=10, help="depth samples per prediction (default 10)")
    p.add_argument("--seed", type=int, default=0, help="seed for the source, planners and robot (default 0)")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="processes simulating the depth samples while planning (default: 2, or 1 on "
                        "a 1-core machine); the plans do not depend on it")
    p.add_argument("--no-capture", action="store_true", help="do not capture once at start")


def build(args: argparse.Namespace):
    """Open source, store and robot factory, the workflow and the app (used by tests too)."""
    from console.app import ConsoleApp, check_host
    from perception.errors import ShelfpickError

    # refuse bad settings before opening anything
    workers = getattr(args, "workers", 1)
    if workers < 1:
        raise ShelfpickError(f"--workers: must be >= 1, got {workers}")
    if args.samples < 1:
        raise ShelfpickError(f"--samples: must be >= 1, got {args.samples}")
    given = args.supervisor_passphrase or os.environ.get(ENV_PASSPHRASE) or ""
    check_host(args.host, given or None)
    if not (args.robot == "sim" or args.robot.startswith("sim?") or args.robot.startswith("tcp://")):
        raise ShelfpickError(f"--robot: expected sim or tcp://HOST:PORT, got {args.robot!r}")

    from console.robot import open_robot
    from console.sources import open_source
    from console.store import DEFAULT_DB, SessionStore
    from console.workflow import Workflow

    passphrase = given or secrets.token_urlsafe(9)
    source = open_source(args.source, seed=args.seed)
    db = Path(args.db) if args.db else DEFAULT_DB
    store = SessionStore(db)          # a folder it cannot make, a file not ours: StoreError, one line
    spec = args.robot
    open_robot(spec, truth=None, seed=args.seed) if spec.startswith("sim") else None  # validates options

    def robot_factory(truth, seed):
        return open_robot(spec, truth=truth, seed=seed)

    wf = Workflow(source, store, robot_factory, passphrase, samples=args.samples, seed=args.seed,
                  workers=workers)
    app = ConsoleApp(wf, host=args.host, port=args.port, passphrase_set=bool(given))
    return app, wf, store, passphrase, bool(given), db


def run(args: argparse.Namespace) -> int:
    import time

    app, wf, store, passphrase, given, db = build(args)
    print(f"shelfpick console: {app.url}  (source {args.source}, robot {args.robot}, database {db})",
          flush=True)
    if not given:
        print(f"supervisor passphrase (generated for this run): {passphrase}", flush=True)
    for note in wf.state.recovered:
        print(f"recovered: {note}", flush=True)
    if not args.no_capture:
        wf.capture()
        st = wf.state
        print(f"first capture: {st.message or ''} {st.error or ''}".rstrip(), flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
        store.close()
    return 0
