"""Predicted risk against what happened, over every stored session (`shelfpick sessions --stats`).

A plan carries a predicted collapse risk per step; the robot reports what it
did (and, a simulated or instrumented one, boxes that collapsed); the console's
look after each step says whether the shelf stood as predicted. Grouping the
executed steps by their predicted risk shows whether the prediction is honest:
steps predicted safe should rarely deviate, risky ones more often.
Pure functions of the rows `SessionStore.step_stats()` returns.
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

BANDS = ((0.0, 0.0, "0%"), (0.0, 0.5, "1-49%"), (0.5, 1.0, "50-100%"))


def band(risk: float) -> str:
    """The predicted-risk band of a step: exactly 0, below one half, one half and above."""
    if risk <= 0.0:
        return BANDS[0][2]
    return BANDS[1][2] if risk < 0.5 else BANDS[2][2]


def _count(rows: Sequence[Mapping[str, Any]], label: str) -> dict:
    n = len(rows)
    verified = [r for r in rows if r["verified"] in ("within", "deviation")]
    dev = sum(r["verified"] == "deviation" for r in verified)
    return {"risk": label, "steps": n,
            "mean_predicted_risk": round(sum(r["collapse_prob"] for r in rows) / n, 3) if n else None,
            "robot_collapses": sum(bool(r["robot_collapse"]) for r in rows),
            "verified": len(verified), "deviations": dev,
            "not_verified": sum(r["verified"] in (None, "unavailable") for r in rows),
            "deviation_rate": round(dev / len(verified), 3) if verified else None}


def risk_table(rows: Sequence[Mapping[str, Any]]) -> list[dict]:
    """One row per predicted-risk band and one for all steps."""
    out = [_count([r for r in rows if band(r["collapse_prob"]) == label], label) for _, _, label in BANDS]
    out.append(_count(list(rows), "all"))
    return out


def session_counts(sessions: Sequence[Mapping[str, Any]]) -> dict[str, int]:
    """How many sessions ended in each status (done, held, failed, stopped, ...)."""
    out: dict[str, int] = {}
    for s in sessions:
        out[str(s.get("status"))] = out.get(str(s.get("status")), 0) + 1
    return dict(sorted(out.items()))


def format_stats(table: Sequence[Mapping[str, Any]], counts: Mapping[str, int]) -> str:
    """The table `shelfpick sessions --stats` prints."""
    cols = [("risk", "PREDICTED RISK"), ("steps", "STEPS"), ("mean_predicted_risk", "MEAN RISK"),
            ("robot_collapses", "ROBOT COLLAPSES"), ("verified", "VERIFIED"), ("deviations", "DEVIATIONS"),
            ("deviation_rate", "DEV RATE"), ("not_verified", "NOT VERIFIED")]
    cells = [[h for _, h in cols]] + [["-" if r.get(k) is None else str(r.get(k)) for k, _ in cols] for r in table]
    widths = [max(len(c[i]) for c in cells) for i in range(len(cols))]
    lines = ["  ".join(c[i].ljust(widths[i]) for i in range(len(cols))).rstrip() for c in cells]
    lines.append("sessions: " + (", ".join(f"{k} {v}" for k, v in counts.items()) or "none"))
    return "\n".join(lines)


__all__ = ["BANDS", "band", "risk_table", "session_counts", "format_stats"]
