"""`shelfpick replay ID --html OUT.html`: export one session as a self-contained web page."""
from __future__ import annotations

import argparse

HELP = "export a stored session as a self-contained HTML replay (opens without the server)"
MAX_ID = 2**63 - 1          # a session id is a SQLite INTEGER


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("id", type=int, help="session id (see `shelfpick sessions`)")
    p.add_argument("--html", required=True, metavar="OUT.html", help="file to write")
    p.add_argument("--db", default=None, help="session database (default ./data/shelfpick.db)")


def run(args: argparse.Namespace) -> int:
    from pathlib import Path

    from shelfpick.console.cmd_sessions import stored
    from shelfpick.console.web.replay import export_html
    from shelfpick.console.store.sessions import DEFAULT_DB, SessionStore, StoreError
    from shelfpick.perception.scene import output_path

    if not 1 <= args.id <= MAX_ID:
        raise StoreError(f"id: expected a session id from 1 to {MAX_ID}, got {args.id}")
    output_path(args.html, "--html")     # never onto a device, FIFO or folder; checked before reading
    db = Path(args.db) if args.db else DEFAULT_DB
    if not db.is_file():
        raise StoreError(f"{db}: no session database here (pass --db PATH)")
    with SessionStore(db, readonly=True) as store:      # replaying never writes to the archive
        rec = stored(lambda: store.load_session(args.id), db, f"session {args.id}")
    try:
        out = stored(lambda: export_html(rec, args.html), db, f"session {args.id}")
    except OSError as exc:
        raise StoreError(f"{args.html}: cannot write the replay ({exc.strerror or exc})") from None
    size = out.stat().st_size
    print(f"session {rec.id}: replay written to {out} ({size / 1024:.0f} KiB, {len(rec.plans)} plans, "
          f"{len(rec.decisions)} decisions)")
    return 0
