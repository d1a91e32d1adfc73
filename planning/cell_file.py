"""Reading a cell file (`cell.toml`) safely: the one reader behind the console's `read_cell` and
`shelfpick plan --cell`, so both refuse the same files with the same one-line errors.

A cell file is a few hundred bytes of TOML. It is opened without blocking and checked to be a
regular file before anything is read (a FIFO would block, a symlink to /dev/zero never ends), and
read up to `MAX_CELL_BYTES`.
"""
from __future__ import annotations

import os
import stat
import sys
from pathlib import Path
from typing import Any

from shelfpick.perception.errors import FormatError

CELL_FORMAT = "shelfpick.cell/1"
MAX_CELL_BYTES = 1 << 20


def _toml(origin: str, field: str) -> Any:
    if sys.version_info >= (3, 11):
        import tomllib
        return tomllib
    try:
        import tomli   # a dependency of shelfpick on Python 3.10
    except ModuleNotFoundError:
        raise FormatError(origin, field, "reading a cell file on Python 3.10 needs tomli (pip install tomli)") from None
    return tomli


def _regular_bytes(path: str, field: str) -> bytes:
    """The file's bytes: refused unless it is a regular file, and past MAX_CELL_BYTES."""
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0))
    except FileNotFoundError:
        raise FormatError(path, field, "cell file not found") from None
    except OSError as exc:
        raise FormatError(path, field, f"cannot read the cell file ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise FormatError(path, field, "not a regular file (a device, FIFO or folder); a cell file is a TOML file")
        if st.st_size > MAX_CELL_BYTES:
            raise FormatError(path, field, f"{st.st_size} bytes; a cell file is at most {MAX_CELL_BYTES} bytes")
        chunks, size = [], 0
        while size <= MAX_CELL_BYTES and (chunk := os.read(fd, MAX_CELL_BYTES + 1 - size)):
            chunks.append(chunk)
            size += len(chunk)
        data = b"".join(chunks)
    except OSError as exc:
        raise FormatError(path, field, f"cannot read the cell file ({exc.strerror or exc})") from None
    finally:
        os.close(fd)
    if len(data) > MAX_CELL_BYTES:
        raise FormatError(path, field, f"more than {MAX_CELL_BYTES} bytes; a cell file is at most {MAX_CELL_BYTES} bytes")
    return data


def read_cell_toml(path: str | Path, field: str = "") -> dict[str, Any]:
    """The cell file's TOML document; a FormatError naming the file (and `field`, e.g. "--cell")
    when it is missing, not a regular file, too big, not UTF-8 or not TOML."""
    origin = str(path)
    data = _regular_bytes(origin, field)
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise FormatError(origin, field, f"cannot read the cell file (not UTF-8 text at byte {exc.start})") from None
    try:
        return _toml(origin, field).loads(text)
    except ValueError as exc:    # tomllib.TOMLDecodeError is a ValueError
        raise FormatError(origin, field, f"not valid TOML ({exc})") from None


__all__ = ["CELL_FORMAT", "MAX_CELL_BYTES", "read_cell_toml"]
