"""One BLAS thread while `perceive` runs.

Why: numpy's OpenBLAS starts a thread per core for every matrix product, and perception's
products are tiny (an image's points times a 3x3 rotation, RANSAC's 2000 points times 100
normals). On 2 shared cores the threads only wait for each other: with them a 640x480 frame took
0.74 s of CPU, with one thread 0.56 s (p50 of 10 tuning frames; benchmarks/perceive_speed.py,
docs/results/perceive-speed.md).
A product's result does not depend on the thread count here (the same frames' outputs are
byte-equal either way). The OpenBLAS libraries already loaded (numpy's, scipy's) are found in
/proc/self/maps and set through their own `*_set_num_threads` call, restored after; where
that is not possible (another platform, another BLAS) nothing changes.
"""
from __future__ import annotations

import contextlib
import ctypes
from collections.abc import Iterator
from pathlib import Path

_SUFFIXES = ("", "64_", "_64")
_PREFIXES = ("scipy_openblas", "openblas")


def _symbols(path: str) -> tuple[ctypes.CDLL, str] | None:
    """(library, pattern of its thread-count symbols) of one OpenBLAS, or None."""
    try:
        lib = ctypes.CDLL(path)      # already loaded: the same handle
    except OSError:
        return None
    for pre in _PREFIXES:
        for suf in _SUFFIXES:
            get, put = f"{pre}_get_num_threads{suf}", f"{pre}_set_num_threads{suf}"
            if hasattr(lib, get) and hasattr(lib, put):
                getattr(lib, get).restype = ctypes.c_int
                getattr(lib, put).argtypes = [ctypes.c_int]
                return lib, pre + "{}" + suf
    return None


def _openblas_libs() -> list[tuple[ctypes.CDLL, str]]:
    """(library, symbol pattern) of each OpenBLAS loaded in this process now (one may load late:
    scipy's comes with scipy.linalg)."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return []
    paths = {p for p in (line.rsplit(" ", 1)[-1] for line in maps.splitlines() if "openblas" in line.lower())
             if p.startswith("/") and ".so" in p}
    found = [_symbols(p) for p in sorted(paths)]     # dlopen of a loaded library: its handle, no load
    return [f for f in found if f is not None]


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """Run the body with one OpenBLAS thread, the previous counts restored after. The count is the
    process's: another thread's products meanwhile run on one thread too (their results are the same)."""
    libs = _openblas_libs()
    before = [getattr(lib, name.format("_get_num_threads"))() for lib, name in libs]
    for (lib, name), n in zip(libs, before):
        if n != 1:
            getattr(lib, name.format("_set_num_threads"))(1)
    try:
        yield
    finally:
        for (lib, name), n in zip(libs, before):
            if n != 1:
                getattr(lib, name.format("_set_num_threads"))(n)
