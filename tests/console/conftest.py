"""Fixtures shared by the console's tests."""
from __future__ import annotations

import pytest


@pytest.fixture()
def server():
    """A real viser server on a free local port, stopped after the test."""
    import viser

    s = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        yield s
    finally:
        s.stop()
