"""perception/__init__.py names the package's public API and imports it only when used."""
from __future__ import annotations

import subprocess
import sys

import pytest


@pytest.mark.parametrize("package", ["shelfpick.perception", "shelfpick.perception.repairs"])
def test_every_public_name_is_the_object_of_its_module(package):
    import importlib

    pkg = importlib.import_module(package)
    # a name that is also a submodule's (perception.render) would be shadowed by the module
    assert not set(pkg.__all__) & {m.rsplit(".", 1)[1] for m in pkg._WHERE.values()}
    for name in pkg.__all__:
        where = importlib.import_module(pkg._WHERE[name])
        assert getattr(pkg, name) is getattr(where, name), name
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        pkg.nope  # noqa: B018


def test_importing_the_package_or_a_command_loads_nothing_heavy():
    code = ("import sys, shelfpick.perception, shelfpick.perception.cmd_perceive; "
            "print(','.join(m for m in ('cv2', 'torch', 'pybullet', 'shelfpick.perception.pipeline') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""

