"""The house rules a newcomer relies on: the one-way flow, no import cycles, a module map that
names every module, and each package's public names resolving."""
from __future__ import annotations

import ast
import importlib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ("perception", "planning", "console", "robotsim")
# what each package may import of the others (perception -> planning -> console; the robot side apart)
ALLOWED = {"perception": set(), "planning": {"perception"}, "console": {"perception", "planning", "robotsim"},
           "robotsim": {"perception", "planning"}}


def _modules() -> dict[str, Path]:
    out = {}
    for pkg in PACKAGES:
        for f in sorted((ROOT / pkg).rglob("*.py")):
            out[".".join(f.relative_to(ROOT).with_suffix("").parts)] = f
    return out


def _type_only(tree: ast.AST) -> set[int]:
    """ids of the import nodes under `if TYPE_CHECKING:` (annotations only, never run)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out |= {id(n) for b in node.body for n in ast.walk(b)}
    return out


def _imports(path: Path, runtime_only: bool = False) -> set[str]:
    """Every project module a file imports, at any level (`runtime_only`: not the type-only ones)."""
    names: set[str] = set()
    tree = ast.parse(path.read_text())
    skip = _type_only(tree) if runtime_only else set()
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}
    return {n for n in names if n.split(".")[0] in PACKAGES}


def test_data_flows_one_way():
    for mod, path in _modules().items():
        pkg = mod.split(".")[0]
        for name in _imports(path):
            other = name.split(".")[0]
            assert other == pkg or other in ALLOWED[pkg], f"{mod} imports {name}"


def test_no_import_cycle_among_modules():
    """Among the imports that run: a module may name, for its annotations only, a type of a
    module that imports it (`if TYPE_CHECKING:`), which never executes."""
    mods = _modules()
    graph = {m: {n for n in _imports(p, runtime_only=True) if n in mods and n != m} for m, p in mods.items()}
    for m in graph:   # a package's __init__ re-exporting lazily is no edge; its modules are
        graph[m] = {n for n in graph[m] if not n.endswith("__init__")}
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path[path.index(n):] + [n]))
            if n not in state:
                visit(n, path + [n])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])


def test_the_module_map_names_every_module():
    doc = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    missing = [m for m in _modules() if not m.endswith("__init__") and f"`{m.rsplit('.', 1)[1]}`" not in doc]
    assert not missing, f"docs/ARCHITECTURE.md does not name {missing}"


@pytest.mark.parametrize("pkg", PACKAGES)
def test_each_package_names_its_public_api(pkg):
    module = importlib.import_module(pkg)
    assert module.__doc__
    for name in getattr(module, "__all__", ()):
        assert getattr(module, name) is not None
    if pkg != "robotsim":
        assert module.__all__
