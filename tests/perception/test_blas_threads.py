"""perceive runs with one BLAS thread and gives the count back (perception/blas_threads.py)."""
from __future__ import annotations

import numpy as np
import pytest

from shelfpick.perception.blas_threads import _openblas_libs, one_blas_thread


def _counts() -> list[int]:
    return [getattr(lib, name.format("_get_num_threads"))() for lib, name in _openblas_libs()]


def test_one_thread_inside_and_the_count_restored_after():
    np.ones((4, 4)) @ np.ones((4, 4))     # numpy's OpenBLAS is loaded
    if not _openblas_libs():
        pytest.skip("no OpenBLAS found in this process (another platform or BLAS)")
    lib, name = _openblas_libs()[0]
    setter = getattr(lib, name.format("_set_num_threads"))
    before = _counts()[0]
    setter(2)
    try:
        with one_blas_thread():
            assert set(_counts()) == {1}
            with one_blas_thread():        # nested (a large image perceived scaled down)
                assert set(_counts()) == {1}
            assert set(_counts()) == {1}
        assert _counts()[0] == 2
    finally:
        setter(before)


def test_the_count_is_restored_when_the_body_raises():
    if not _openblas_libs():
        pytest.skip("no OpenBLAS found in this process")
    lib, name = _openblas_libs()[0]
    setter = getattr(lib, name.format("_set_num_threads"))
    before = _counts()[0]
    setter(2)
    try:
        with pytest.raises(ValueError):
            with one_blas_thread():
                raise ValueError("boom")
        assert _counts()[0] == 2
    finally:
        setter(before)
