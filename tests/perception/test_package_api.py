"""perception/__init__.py names the package's public API and imports it only when used."""
from __future__ import annotations

import subprocess
import sys

import pytest


def test_every_public_name_is_the_object_of_its_module():
    import importlib

    import perception

    # a name that is also a submodule's (perception.render) would be shadowed by the module
    assert not set(perception.__all__) & {m.rsplit(".", 1)[1] for m in perception._WHERE.values()}
    for name in perception.__all__:
        where = importlib.import_module(perception._WHERE[name])
        assert getattr(perception, name) is getattr(where, name), name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        perception.nope  # noqa: B018


def test_importing_the_package_or_a_command_loads_nothing_heavy():
    code = ("import sys, perception, perception.cmd_perceive; "
            "print(','.join(m for m in ('cv2', 'torch', 'pybullet', 'perception.pipeline') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""

