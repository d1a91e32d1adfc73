"""Freed arrays' memory kept in the process's heap while `perceive` runs again and again.

Why: a frame makes and drops thousands of arrays of 0.3-2.4 MB (full-frame masks, depth and point
images). glibc's malloc serves such a block from fresh pages of its own (mmap) or hands the top of
its heap back to the kernel once it is freed, so the next array's pages are faulted in and zeroed
by the kernel again, page by page: ~10000 page faults a 640x480 frame. With the heap kept, the next
array reuses pages already there (a third of the faults; perceive's CPU 8-15 % less on the tuning
frames, its peak memory ~30 MB more).

What is computed does not change (the same values land in memory elsewhere). The settings are the
process's (glibc's mallopt; it has no call to read them back, so they are set, never restored): the
process keeps up to `TRIM_AT` of freed heap instead of returning it at once. Where malloc is not
glibc's, nothing changes. So the process's owner sets them, at its start: `shelfpick perceive`
and the console do; `perceive()` itself does not (a library call changes no process-wide setting
behind its caller's back), and a program that calls it frame after frame may.
"""
from __future__ import annotations

import ctypes

# glibc's mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
MMAP_AT = 64 << 20     # blocks below this come from the heap (glibc's default moves from 128 kB up)
TRIM_AT = 512 << 20    # freed heap beyond this at its top goes back to the kernel (default: 128 kB up)


def keep_freed_pages() -> bool:
    """Set glibc's malloc to serve blocks below `MMAP_AT` from its heap and to keep up to `TRIM_AT`
    of freed heap (see the module docstring); True where it took both, False where malloc is not
    glibc's (nothing set)."""
    try:
        mallopt = ctypes.CDLL(None).mallopt
    except (OSError, AttributeError, TypeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_AT)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_AT))
