"""`shelfpick sessions`: list the console's stored sessions as a table; `--stats`: predicted risk
against what happened (console/store/stats.py)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Callable, TypeVar

T = TypeVar("T")

HELP = "list stored console sessions (id, start, source, boxes, task, status)"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", default=None, help="session database (default ./data/shelfpick.db)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--stats", action="store_true",
                   help="over all sessions: executed steps by predicted collapse risk, robot-reported "
                        "collapses, deviations seen by the look after each step")


def stored(read: Callable[[], T], db: Path, what: str) -> T:
    """`read()`, with a record in the database that is not JSON, is nested too deep or does not
    have the shape a record has (a damaged or hand-edited archive) made one line naming the
    database: StoreError, exit 2, instead of a traceback."""
    from shelfpick.console.store.sessions import StoreError
    from shelfpick.perception.errors import ShelfpickError

    try:
        return read()
    except ShelfpickError:
        raise
    except RecursionError:
        raise StoreError(f"{db}: {what}: a stored record is nested too deep to read") from None
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        why = str(exc).splitlines()[0][:120] if str(exc) else ""
        raise StoreError(f"{db}: {what}: a stored record cannot be read ({type(exc).__name__}: {why!r})") from None


def format_table(rows: list[dict]) -> str:
    cols = [("id", "ID"), ("started", "STARTED (UTC)"), ("source", "SOURCE"), ("n_boxes", "BOXES"),
            ("task", "TASK"), ("n_plans", "PLANS"), ("status", "STATUS")]
    cells = [[h for _, h in cols]] + [["" if r.get(k) is None else str(r.get(k)) for k, _ in cols] for r in rows]
    widths = [max(len(c[i]) for c in cells) for i in range(len(cols))]
    return "\n".join("  ".join(c[i].ljust(widths[i]) for i in range(len(cols))).rstrip() for c in cells)


def run(args: argparse.Namespace) -> int:
    from shelfpick.console.store.sessions import DEFAULT_DB, SessionStore, StoreError

    db = Path(args.db) if args.db else DEFAULT_DB
    if not db.is_file():
        raise StoreError(f"{db}: no session database here (start `shelfpick console`, or pass --db PATH)")
    # read-only: an archive on a read-only disk lists; a SQLite file that is not ours is refused untouched
    with SessionStore(db, readonly=True) as store:
        rows = stored(store.list_sessions, db, "sessions")
        steps = stored(store.step_stats, db, "robot events") if args.stats else []
    if args.stats:
        from shelfpick.console.store.stats import format_stats, risk_table, session_counts

        table, counts = risk_table(steps), session_counts(rows)
        print(json.dumps({"by_risk": table, "sessions": counts}, indent=2) if args.json
              else format_stats(table, counts))
        return 0
    if args.json:
        print(json.dumps(rows, indent=2))
    elif not rows:
        print(f"{db}: no sessions yet")
    else:
        print(format_table(rows))
    return 0
