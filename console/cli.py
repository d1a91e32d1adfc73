"""The one `shelfpick` command and its subcommands.

Each subcommand lives in a module of the package that owns it and exposes
`HELP` (one line), `add_arguments(parser)` and `run(args) -> int`. Those
modules import nothing heavy at module level (no torch, pybullet or viser),
so `shelfpick --help` stays instant. A `ShelfpickError` is the user's to fix:
it is printed as one line and the exit code is 2, with no traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys

COMMANDS: dict[str, str] = {
    "plan": "planning.cmd_plan",
    "simulate": "planning.cmd_simulate",
    "scenes": "planning.cmd_scenes",
    "bench": "planning.cmd_bench",
    "render": "perception.cmd_render",
    "perceive": "perception.cmd_perceive",
    "train-seg": "perception.cmd_train_seg",
    "perceive-bench": "perception.cmd_perceive_bench",
    "console": "console.cmd_console",
    "sessions": "console.cmd_sessions",
    "replay": "console.cmd_replay",
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="shelfpick",
        description="Collapse- and collision-aware box picking from shelves.")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, modname in COMMANDS.items():
        try:
            mod = importlib.import_module(modname)
        except ModuleNotFoundError as exc:
            if exc.name != modname:
                raise
            continue  # a subcommand whose module is not built yet
        p = sub.add_parser(name, help=mod.HELP, description=mod.HELP)
        mod.add_arguments(p)
        p.set_defaults(_run=mod.run)
    return parser


def main(argv: list[str] | None = None) -> int:
    from perception.errors import ShelfpickError

    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "_run", None):
        parser.print_help()
        return 2
    try:
        return int(args._run(args) or 0)
    except ShelfpickError as exc:
        print(f"shelfpick {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"shelfpick {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
