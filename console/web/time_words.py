"""Times from the session store as a person reads them."""
from __future__ import annotations


def start_time_words(t: float | str | None) -> str:
    """A time from the store as a person reads it: "2026-11-28 13:18:58 UTC" (the store writes ISO
    times with milliseconds and an offset; another offset is kept as "+01:00"); text that is no
    time comes back as it is."""
    from datetime import datetime, timezone

    if isinstance(t, (int, float)):
        when = datetime.fromtimestamp(t, timezone.utc)
    else:
        try:
            when = datetime.fromisoformat(str(t))
        except ValueError:
            return str(t or "")
    off, z = when.utcoffset(), when.strftime("%z")
    zone = "" if off is None else " UTC" if not off else f" {z[:3]}:{z[3:]}"
    return when.strftime("%Y-%m-%d %H:%M:%S") + zone
