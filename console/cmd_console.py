"""`shelfpick console`: start the operator console (viser web app) and print its URL.

Settings come from the command line, else a cell file (`--cell cell.toml`, console/cell.py), else
the defaults; everything is checked, and every optional library the settings need is looked up,
before the database is opened or the server starts. SIGTERM (a service manager stopping it) stops
a robot run as the Stop button does, waits for the robot to acknowledge, closes the server and the
database, and exits 143.
"""
from __future__ import annotations

import argparse
import importlib.util
import logging
import os
import secrets
import signal
import sys
import threading
from pathlib import Path

log = logging.getLogger(__name__)

HELP = "start the operator console: capture, compare plans, approve, execute, replay (web app)"
ENV_PASSPHRASE = "SHELFPICK_SUPERVISOR_PASSPHRASE"
EXIT_TERMINATED = 143
STOP_WAIT_S = 30.0       # how long SIGTERM waits for a stopped robot run to end before closing
DEFAULTS = {"source": "demo", "host": "127.0.0.1", "port": 8080, "db": None, "robot": "sim", "samples": 10,
            "seed": 0, "workers": min(2, os.cpu_count() or 1)}


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--cell", default=None, metavar="CELL.toml",
                   help="the cell file: shelf, camera, segmenter and weights, robot URL and transform, safety "
                        "settings (docs/cli.md, examples/cell.toml); options given here override it")
    p.add_argument("--source", default=None,
                   help="demo | files:DIR | realsense | bag:FILE (default: demo, synthetic shelves)")
    p.add_argument("--host", default=None,
                   help="address to listen on (default 127.0.0.1; others need a supervisor passphrase)")
    p.add_argument("--port", type=int, default=None, help="port (0 = any free port; default 8080)")
    p.add_argument("--db", default=None, help="session database (default ./data/shelfpick.db, as `shelfpick sessions`)")
    p.add_argument("--robot", default=None, help="sim | tcp://HOST:PORT (default sim)")
    p.add_argument("--supervisor-passphrase", default=None,
                   help=f"passphrase for Approve/Reject (or env {ENV_PASSPHRASE}); at least 12 characters "
                        "on a non-local --host; generated and printed when unset on a local address")
    p.add_argument("--samples", type=int, default=None, help="depth samples per prediction (default 10)")
    p.add_argument("--seed", type=int, default=None, help="seed for the source, planners and robot (default 0)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes simulating the depth samples while planning (default: 2, or 1 on "
                        "a 1-core machine); the plans do not depend on it")
    p.add_argument("--no-capture", action="store_true", help="do not capture once at start")


def settle(args: argparse.Namespace):
    """Command line over cell file over defaults, into `args`; the cell (or None)."""
    from console.cell import read_cell

    cell = read_cell(args.cell) if getattr(args, "cell", None) else None
    from_cell = {}
    if cell is not None:
        from_cell = {"source": cell.source_spec(), "robot": cell.robot, **cell.safety}
    for key, default in DEFAULTS.items():
        if getattr(args, key, None) is None:
            v = from_cell.get(key)
            setattr(args, key, v if v is not None else default)
    return cell


def need(module: str, extra: str, why: str) -> None:
    """Refuse to start, in one line, when an optional library the settings need is not installed."""
    from perception.errors import ShelfpickError

    if importlib.util.find_spec(module) is None:
        raise ShelfpickError(f"{why} needs the optional library {module!r}, which is not installed here: "
                             f"pip install 'shelfpick[{extra}]'")


def check_libraries(args: argparse.Namespace, cell) -> None:
    """Every optional library the chosen settings import, looked up before anything starts."""
    need("viser", "console", "the console")
    need("cv2", "perception", "the console")
    where = f"{cell.path}: camera.source" if cell is not None and cell.source and args.source == cell.source_spec() \
        else "--source"
    base = args.source.split("?")[0]
    if base == "realsense" or base.startswith("bag:"):
        need("pyrealsense2", "realsense", f"{where} {base}")
    seg = cell.segmenter if cell is not None else "auto"
    if seg in ("yolo", "learned") or (cell is not None and cell.weights and seg == "auto"):
        need("torch", "learned", f"{cell.path}: perception.segmenter {seg}")
        if seg != "learned":
            need("ultralytics", "learned", f"{cell.path}: perception.segmenter {seg}")


def build(args: argparse.Namespace):
    """Open source, store and robot factory, the workflow and the app (used by tests too)."""
    from perception.errors import ShelfpickError

    cell = settle(args)
    # refuse bad settings before opening anything
    from console.cell import check_robot_spec
    from planning.cmd_plan import SAMPLES, SEEDS, WORKERS

    workers = getattr(args, "workers", 1)
    for flag, value, (lo, hi) in (("--workers", workers, WORKERS), ("--samples", args.samples, SAMPLES),
                                  ("--seed", args.seed, SEEDS)):   # the cell file's bounds: memory is per sample
        if not lo <= value <= hi:
            raise ShelfpickError(f"{flag}: must be from {lo} to {hi}, got {value}")
    args.robot = check_robot_spec(args.robot, "--robot")     # the cell file's robot bounds, one validator
    check_libraries(args, cell)
    from console.app import ConsoleApp, check_host

    given = args.supervisor_passphrase or os.environ.get(ENV_PASSPHRASE) or ""
    check_host(args.host, given or None)
    if not (args.robot == "sim" or args.robot.startswith("sim?") or args.robot.startswith("tcp://")):
        raise ShelfpickError(f"--robot: expected sim or tcp://HOST:PORT, got {args.robot!r}")

    from console.robot import open_robot
    from console.sources import open_source
    from console.store import DEFAULT_DB, SessionStore
    from console.workflow import Workflow

    segmenter, options, tolerance = None, {}, None
    if cell is not None:
        from perception.scene import Shelf
        from perception.segment import load_segmenter

        kind = "yolo" if cell.weights and cell.segmenter == "auto" else cell.segmenter
        segmenter = load_segmenter(cell.weights, kind)
        if cell.shelf is not None:
            options["shelf"] = Shelf(*cell.shelf)
        if not cell.catalogue:
            options["catalogue"] = None
        tolerance = cell.tolerance()
    passphrase = given or secrets.token_urlsafe(9)
    source = open_source(args.source, seed=args.seed)
    db = Path(args.db) if args.db else DEFAULT_DB
    spec = args.robot
    open_robot(spec, truth=None, seed=args.seed) if spec.startswith("sim") else None  # validates options
    if spec.startswith("tcp://"):
        from console.robot_tcp import TcpRobot

        TcpRobot.from_spec(spec)      # a bad transform file or option: one line before anything opens
    store = SessionStore(db)          # a folder it cannot make, a file not ours: StoreError, one line

    def robot_factory(truth, seed):
        return open_robot(spec, truth=truth, seed=seed)

    wf = Workflow(source, store, robot_factory, passphrase, samples=args.samples, seed=args.seed,
                  workers=workers, segmenter=segmenter, tolerance=tolerance, perceive_options=options)
    app = ConsoleApp(wf, host=args.host, port=args.port, passphrase_set=bool(given))
    return app, wf, store, passphrase, bool(given), db


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C (exit 0) or SIGTERM (the robot stopped, then exit 143)."""
    return serve(build(args), args)


def serve(parts: tuple, args: argparse.Namespace) -> int:
    """Print where the console is, capture once, wait for Ctrl-C or SIGTERM; close everything.

    C code's printf() is kept off stdout once for the whole run (perception.stdio): a per-connect
    redirection of fd 1 and 2 would swallow what other threads print or log meanwhile."""
    from perception.stdio import c_output_detached

    with c_output_detached():
        return _serve(parts, args)


def _serve(parts: tuple, args: argparse.Namespace) -> int:
    app, wf, store, passphrase, given, db = parts
    done = threading.Event()
    terminated = threading.Event()

    def on_term(signum, frame) -> None:   # runs in the main thread, between bytecodes
        terminated.set()
        done.set()

    previous = signal.signal(signal.SIGTERM, on_term) if threading.current_thread() is threading.main_thread() \
        else None
    try:
        print(f"shelfpick console: {app.url}  (source {args.source}, robot {args.robot}, database {db})",
              flush=True)
        if not given:
            print(f"supervisor passphrase (generated for this run): {passphrase}", flush=True)
        for note in wf.state.recovered:   # on stdout with the URL, as README's safety rules say
            print(f"recovered: {note}", flush=True)
        if not args.no_capture and not terminated.is_set():
            wf.capture()
            st = wf.state
            log.info("first capture: %s", f"{st.message or ''} {st.error or ''}".strip())
        try:
            while not done.wait(3600):
                pass
        except KeyboardInterrupt:
            pass
        if terminated.is_set():
            stop_for_sigterm(wf)
    finally:
        app.stop()
        store.close()
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
    if terminated.is_set():
        log.info("stopped by SIGTERM; database %s closed", db)
        return EXIT_TERMINATED
    return 0


def stop_for_sigterm(wf) -> None:
    """Stop a robot run as the Stop button does (recorded as by 'SIGTERM') and wait for it to end."""
    running = wf.state.robot in ("running", "stopping")
    if running:
        log.warning("SIGTERM: stopping the robot run")
    wf.stop(who="SIGTERM")            # also withdraws an approval not yet run
    st = wf.wait_robot(timeout=STOP_WAIT_S)
    log.info("robot: %s", st.robot)
    sys.stdout.flush()
