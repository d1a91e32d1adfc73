"""Errors that reach the user as one line (the CLI prints them and exits 2).

Every package raises these for bad input so that the command line and the
console can tell a user's mistake from a bug: a `ShelfpickError` is the
user's to fix and its message names the file, the field and the value.
"""
from __future__ import annotations


class ShelfpickError(Exception):
    """A problem the user can fix; the message is shown as is."""


class FormatError(ShelfpickError, ValueError):
    """A scene, plan or camera document that does not follow FORMATS.md."""

    def __init__(self, origin: str, field: str, problem: str):
        self.origin = origin
        self.field = field
        self.problem = problem
        where = f"{origin}: " if origin else ""
        super().__init__(f"{where}{field}: {problem}" if field else f"{where}{problem}")


class SceneError(ShelfpickError):
    """A scene that is well formed but physically unusable (overlaps, unstable)."""


class PerceptionError(ShelfpickError):
    """An image, depth map, camera or weights file that perception cannot use."""
