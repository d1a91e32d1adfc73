"""`shelfpick console`: start the operator console (viser web app) and print its URL.

Settings come from the command line, else a cell file (`--cell cell.toml`, console/cell.py), else
the defaults; everything is checked, and every optional library the settings need is looked up,
before the database is opened or the server starts. SIGTERM (a service manager stopping it) and
Ctrl-C (SIGINT) stop a robot run as the Stop button does, wait for the robot to acknowledge, close
the server and the database, and exit 143 and 130.
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
import time
from pathlib import Path

log = logging.getLogger(__name__)

HELP = "start the operator console: capture, compare plans, approve, execute, replay (web app)"
ENV_PASSPHRASE = "SHELFPICK_SUPERVISOR_PASSPHRASE"
EXIT_TERMINATED = 143
STOP_WAIT_S = 30.0       # how long SIGTERM or Ctrl-C waits for a stopped robot run to end before closing
EXIT_INTERRUPTED = 130   # Ctrl-C (SIGINT)
SERVER_START_S = 60.0    # how long the web server may take to start listening
DEFAULTS = {"source": "demo", "host": "127.0.0.1", "port": 8080, "db": None, "robot": "sim", "samples": 10,
            "seed": 0, "workers": min(2, os.cpu_count() or 1), "allow_origins": ()}
PASSPHRASE_FILE_MAX = 4096   # bytes: a passphrase file is one line


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
                   help=f"passphrase for Approve/Reject; other users can read it in `ps`: prefer "
                        f"--supervisor-passphrase-file or env {ENV_PASSPHRASE}. On a non-local --host it must "
                        "not be trivial (docs/cli.md); generated and printed when unset on a local address")
    p.add_argument("--supervisor-passphrase-file", default=None, metavar="FILE",
                   help="read the supervisor passphrase from FILE (its first line; at most 4 KiB)")
    p.add_argument("--allow-origin", dest="allow_origins", action="append", default=None, metavar="URL",
                   help="a browser origin besides the console's own that may drive it, e.g. a reverse proxy's "
                        "https://console.example:8443 (repeatable; the cell file's safety.allow_origins)")
    p.add_argument("--samples", type=int, default=None, help="depth samples per prediction (default 10)")
    p.add_argument("--seed", type=int, default=None, help="seed for the source, planners and robot (default 0)")
    p.add_argument("--workers", type=int, default=None,
                   help="processes simulating the depth samples while planning (default: 2, or 1 on "
                        "a 1-core machine); the plans do not depend on it")
    p.add_argument("--no-capture", action="store_true", help="do not capture once at start")


def settle(args: argparse.Namespace):
    """Command line over cell file over defaults, into `args`; the cell (or None)."""
    from shelfpick.console.cell import read_cell

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
    from shelfpick.perception.errors import ShelfpickError

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
    weights = str(cell.weights) if cell is not None and cell.weights else ""
    # yolo (or auto with weights) runs on torch; learned runs an .onnx on onnxruntime, a .pt on torch
    on_torch = seg == "yolo" or bool(weights) and (seg == "auto" or not weights.endswith(".onnx"))
    if seg in ("yolo", "learned") or on_torch:
        need("torch" if on_torch else "onnxruntime", "train" if on_torch else "perception",
             f"{cell.path}: perception.segmenter {seg}")
        if seg != "learned":
            need("ultralytics", "train", f"{cell.path}: perception.segmenter {seg}")


def build(args: argparse.Namespace):
    """Open source, store and robot factory, the workflow and the app (used by tests too)."""
    cell = settle(args)
    workers = _check_settings(args, cell)   # refuse bad settings before opening anything
    from shelfpick.console.web.app import ConsoleApp, check_host

    given, where = supervisor_passphrase(args)
    check_host(args.host, given or None, where)

    from shelfpick.console.robot.drivers import open_robot
    from shelfpick.console.sources import open_source
    from shelfpick.console.store.sessions import DEFAULT_DB, SessionStore
    from shelfpick.console.workflow.machine import Workflow

    segmenter, options, tolerance = _perception_settings(cell)
    passphrase = given or secrets.token_urlsafe(9)
    spec = args.robot
    _check_robot_transform(spec)
    check_listen(args.host)           # an address not of this machine: one line, not a start that hangs
    source = open_source(args.source, seed=args.seed)
    db = Path(args.db) if args.db else DEFAULT_DB
    store = SessionStore(db)          # a folder it cannot make, a file not ours: StoreError, one line

    def robot_factory(truth, seed):
        return open_robot(spec, truth=truth, seed=seed)

    wf = Workflow(source, store, robot_factory, passphrase, samples=args.samples, seed=args.seed,
                  workers=workers, segmenter=segmenter, tolerance=tolerance, perceive_options=options,
                  priors=cell.priors() if cell is not None else None)
    try:
        app = start_app(lambda: ConsoleApp(wf, host=args.host, port=args.port, passphrase_set=bool(given),
                                           allow_origins=tuple(args.allow_origins or ())),
                        f"--host {args.host} --port {args.port}")
    except BaseException:
        wf.close()
        store.close()
        raise
    return app, wf, store, passphrase, bool(given), db


def _check_settings(args: argparse.Namespace, cell) -> int:
    """The numbers, the robot spec and the port within their bounds (the cell file's: memory is per
    sample), and every optional library they need installed; the worker count."""
    from shelfpick.console.cell import check_robot_spec
    from shelfpick.perception.errors import ShelfpickError
    from shelfpick.planning.cmd_plan import SAMPLES, SEEDS, WORKERS

    workers = getattr(args, "workers", 1)
    for flag, value, (lo, hi) in (("--workers", workers, WORKERS), ("--samples", args.samples, SAMPLES),
                                  ("--seed", args.seed, SEEDS)):
        if not lo <= value <= hi:
            raise ShelfpickError(f"{flag}: must be from {lo} to {hi}, got {value}")
    args.robot = check_robot_spec(args.robot, "--robot")     # the one check of a spec's text: kind, options, bounds
    if not 0 <= args.port <= 65535:    # the server thread would die on it and leave the start waiting
        raise ShelfpickError(f"--port: expected 1-65535, or 0 for any free port, got {args.port}")
    check_libraries(args, cell)
    return workers


def _perception_settings(cell):
    """(segmenter, perceive options, tolerance) of the cell file: its segmenter and weights, shelf,
    catalogue and tolerances; (None, {}, None) without one (the defaults)."""
    if cell is None:
        return None, {}, None
    from shelfpick.perception.scene import Shelf
    from shelfpick.perception.segment import load_segmenter

    options = {}
    kind = "yolo" if cell.weights and cell.segmenter == "auto" else cell.segmenter
    segmenter = load_segmenter(cell.weights, kind)
    if cell.shelf is not None:
        options["shelf"] = Shelf(*cell.shelf)
    if not cell.catalogue:
        options["catalogue"] = None
    return segmenter, options, cell.tolerance()


def _check_robot_transform(spec: str) -> None:
    """A TCP robot's transform (its file, or position and orientation), read as the driver reads it:
    what the spec's text alone (`check_robot_spec`, which has passed) cannot tell, said in one line
    before anything opens, not at the first run. A sim spec has nothing more to check."""
    if spec.startswith("tcp://"):
        from shelfpick.console.robot.tcp import TcpRobot

        TcpRobot.from_spec(spec)


def supervisor_passphrase(args: argparse.Namespace) -> tuple[str, str]:
    """(passphrase, where it came from): --supervisor-passphrase-file, else --supervisor-passphrase,
    else the environment, else "" (one is generated). Both options at once are refused; the option
    itself draws a warning once the console runs (`_serve`), since other users see it in `ps`."""
    from shelfpick.perception.errors import ShelfpickError

    path, text = getattr(args, "supervisor_passphrase_file", None), args.supervisor_passphrase
    if path is not None and text is not None:
        raise ShelfpickError("--supervisor-passphrase and --supervisor-passphrase-file: give one of them")
    if path is not None:
        return read_passphrase_file(path), f"--supervisor-passphrase-file {path}"
    if text is not None:
        return text, "--supervisor-passphrase"
    return os.environ.get(ENV_PASSPHRASE) or "", ENV_PASSPHRASE


def read_passphrase_file(path: str) -> str:
    """The first line of a regular file of at most PASSPHRASE_FILE_MAX bytes (its line end dropped);
    one-line ShelfpickError for anything else. A file others may read draws a warning."""
    import stat

    from shelfpick.perception.errors import ShelfpickError

    where = f"--supervisor-passphrase-file {path}"
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)     # a FIFO must not block the start
        with os.fdopen(fd, "rb") as f:
            st = os.fstat(f.fileno())
            if not stat.S_ISREG(st.st_mode):
                raise ShelfpickError(f"{where}: not a regular file")
            if st.st_size > PASSPHRASE_FILE_MAX:
                raise ShelfpickError(f"{where}: {st.st_size} bytes, a passphrase file holds at most "
                                     f"{PASSPHRASE_FILE_MAX}")
            data = f.read(PASSPHRASE_FILE_MAX + 1)
    except OSError as exc:
        raise ShelfpickError(f"{where}: cannot read it ({exc.strerror or exc})") from None
    try:
        lines = data.decode("utf-8").splitlines()
    except UnicodeDecodeError:
        raise ShelfpickError(f"{where}: not UTF-8 text") from None
    if not lines or not lines[0]:
        raise ShelfpickError(f"{where}: the first line is empty")
    if st.st_mode & 0o077:
        log.warning("%s: other users may read it (mode %o); chmod 600 it", where, stat.S_IMODE(st.st_mode))
    return lines[0]


def check_listen(host: str) -> None:
    """Refuse, in one line, an address this machine cannot listen on (the web server would try
    1000 ports on it and leave the start waiting for ever)."""
    import socket

    from shelfpick.perception.errors import ShelfpickError

    try:
        infos = socket.getaddrinfo(host, 0, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
        family, _, _, _, addr = infos[0]
        with socket.socket(family, socket.SOCK_STREAM) as sock:
            sock.bind(addr)
    except (OSError, UnicodeError, IndexError) as exc:
        raise ShelfpickError(f"--host: cannot listen on {host!r} ({exc})") from None


def start_app(make, where: str, timeout: float = SERVER_START_S):
    """`make()` (the app, whose web server starts on a thread of its own), or one-line ShelfpickError.

    viser waits for its server thread to say "listening"; a thread that dies first (an OverflowError
    on a port out of range, say) would leave that wait, and the command, hanging for ever. So the app
    is made on a helper thread, and an exception in any thread meanwhile, or no server after
    `timeout` s, ends the start in one line."""
    from shelfpick.perception.errors import ShelfpickError

    made: list = []
    failed: list[BaseException] = []
    previous = threading.excepthook

    def caught(hook_args) -> None:     # no traceback: the failure is said in one line below
        failed.append(hook_args.exc_value)

    def make_it() -> None:
        try:
            made.append(make())
        except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
            failed.append(exc)

    threading.excepthook = caught
    try:
        maker = threading.Thread(target=make_it, name="shelfpick-server-start", daemon=True)
        maker.start()
        end = time.monotonic() + timeout
        while maker.is_alive() and not failed and time.monotonic() < end:
            maker.join(0.05)
    finally:
        threading.excepthook = previous
    if made:
        return made[0]
    if failed:
        exc = failed[0]
        if isinstance(exc, ShelfpickError):
            raise exc
        raise ShelfpickError(f"the web server could not start ({where}): {exc.__class__.__name__}: {exc}")
    raise ShelfpickError(f"the web server did not start within {timeout:g} s ({where})")


def run(args: argparse.Namespace) -> int:
    """Serve until Ctrl-C (the robot stopped, then exit 130) or SIGTERM (the same, exit 143)."""
    return serve(build(args), args)


def serve(parts: tuple, args: argparse.Namespace) -> int:
    """Print where the console is, capture once, wait for Ctrl-C or SIGTERM; close everything.

    C code's printf() is kept off stdout once for the whole run (perception.stdio): a per-connect
    redirection of fd 1 and 2 would swallow what other threads print or log meanwhile."""
    from shelfpick.perception.heap_pages import keep_freed_pages
    from shelfpick.perception.stdio import c_output_detached

    keep_freed_pages()        # the console perceives capture after capture (perception.heap_pages)
    with c_output_detached():
        return _serve(parts, args)


def _serve(parts: tuple, args: argparse.Namespace) -> int:
    app, wf, store, passphrase, given, db = parts
    done = threading.Event()
    got: list[int] = []       # the first of SIGTERM / SIGINT (Ctrl-C): both stop a run, then exit

    def on_signal(signum, frame) -> None:   # runs in the main thread, between bytecodes
        if not got:
            got.append(signum)
        done.set()

    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous = {sig: signal.signal(sig, on_signal) for sig in (signal.SIGTERM, signal.SIGINT)}
    try:
        print(f"shelfpick console: {app.url}  (source {args.source}, robot {args.robot}, database {db})",
              flush=True)
        if not given:
            print(f"supervisor passphrase (generated for this run): {passphrase}", flush=True)
        elif getattr(args, "supervisor_passphrase", None) is not None:
            log.warning("--supervisor-passphrase is visible to other users in `ps`; use "
                        "--supervisor-passphrase-file or %s instead", ENV_PASSPHRASE)
        for note in wf.state.recovered:   # on stdout with the URL, as README's safety rules say
            print(f"recovered: {note}", flush=True)
        if not args.no_capture and not got:
            wf.capture()
            st = wf.state
            log.info("first capture: %s", f"{st.message or ''} {st.error or ''}".strip())
        try:
            while not done.wait(3600):
                pass
        except KeyboardInterrupt:     # no handler of ours (not the main thread): still stop the run
            got.append(signal.SIGINT)
        if got:
            stop_for_signal(wf, signal.Signals(got[0]).name)
    finally:
        app.stop()
        store.close()
        for sig, handler in previous.items():
            signal.signal(sig, handler)
    if got:
        name = signal.Signals(got[0]).name
        log.info("stopped by %s; database %s closed", name, db)
        return EXIT_TERMINATED if got[0] == signal.SIGTERM else EXIT_INTERRUPTED
    return 0


def stop_for_signal(wf, who: str) -> None:
    """Stop a robot run as the Stop button does (recorded as by `who`: SIGTERM or SIGINT) and wait
    for it to end."""
    running = wf.state.robot in ("running", "stopping")
    if running:
        log.warning("%s: stopping the robot run", who)
    wf.stop(who=who)                  # also withdraws an approval not yet run
    st = wf.wait_robot(timeout=STOP_WAIT_S)
    log.info("robot: %s", st.robot)
    sys.stdout.flush()


def stop_for_sigterm(wf) -> None:
    """`stop_for_signal` as SIGTERM (kept for callers of the older name)."""
    stop_for_signal(wf, "SIGTERM")
