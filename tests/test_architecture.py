"""The house rules a newcomer relies on: the one-way flow, no import cycles, no module-level state
that functions change, a module map that names every module, and each package's public names
resolving."""
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


def _imports(path: Path) -> set[str]:
    """Every project module a file imports, at any level."""
    names: set[str] = set()
    tree = ast.parse(path.read_text())
    for node in ast.walk(tree):
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


def import_graph() -> dict[str, dict[str, str]]:
    """module -> {module it imports: where (file:line, and how)}, over the four packages.

    What counts as an import: every `import` / `from ... import` statement in a module, wherever it
    stands: at module level, inside a function or method (it runs when called), and under
    `if TYPE_CHECKING:` (never run, but it names a module that needs this one: the two are one idea
    in two files, and a type checker loads them as a cycle). Relative imports are resolved. `from
    pkg import name` is an edge to `pkg.name` when that is a module, else to `pkg` (its __init__).
    Not counted: the packages' lazy public-name tables (`_WHERE` in an __init__, read by
    importlib.import_module when a name is first used), and the implicit import of a module's parent
    packages (their __init__ files import nothing of the package at load)."""
    names = {}
    for mod, path in _modules().items():
        names[mod[: -len(".__init__")] if mod.endswith(".__init__") else mod] = (mod, path)

    def module(name: str) -> str | None:      # the longest project module that `name` is or is in
        while name and name not in names:
            name = name.rpartition(".")[0]
        return name or None

    graph: dict[str, dict[str, str]] = {}
    for name, (mod, path) in names.items():
        tree = ast.parse(path.read_text())
        typing_only = {id(n) for node in ast.walk(tree) if isinstance(node, ast.If)
                       and "TYPE_CHECKING" in ast.unparse(node.test) for b in node.body for n in ast.walk(b)}
        in_function = {id(n) for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                       for n in ast.walk(node) if n is not node}
        edges: dict[str, str] = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                targets = [module(a.name) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    pkg = mod.split(".")[:-1]            # the package a module (or an __init__) is in
                    pkg = pkg[: len(pkg) - (node.level - 1)]
                    base = ".".join(pkg + ([node.module] if node.module else []))
                targets = [module(f"{base}.{a.name}") for a in node.names]
            else:
                continue
            how = ("under TYPE_CHECKING" if id(node) in typing_only else
                   "in a function" if id(node) in in_function else "at module level")
            for t in targets:
                if t and t != name:
                    edges.setdefault(t, f"{path.relative_to(ROOT)}:{node.lineno} {how}")
        graph[name] = edges
    return graph


def import_cycles(graph: dict[str, dict[str, str]]) -> list[tuple[list[str], list[str]]]:
    """Each group of modules that import each other (a strongly connected component of more than one
    module, Tarjan): its modules, and one shortest cycle through the first of them: [a, b, ..., a]."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[set[str]] = []

    def connect(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = set()
            while True:
                w = stack.pop()
                group.add(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(group)

    for v in sorted(graph):
        if v not in index:
            connect(v)
    cycles = []
    for group in groups:                    # a shortest way from the group's first module back to it
        start = min(group)
        paths = {start: [start]}
        frontier = [start]
        while frontier:
            nxt = []
            for v in frontier:
                for w in sorted(graph[v]):
                    if w == start:
                        cycles.append((sorted(group), paths[v] + [start]))
                        nxt = []
                        break
                    if w in group and w not in paths:
                        paths[w] = paths[v] + [w]
                        nxt.append(w)
                else:
                    continue
                break
            frontier = nxt
    return sorted(cycles)


def test_no_import_cycle_among_modules():
    """No two modules import each other, directly or round a longer loop, counting every import
    (see `import_graph`): a cycle is broken by moving the shared piece below both, never by hiding
    an import in a function or under TYPE_CHECKING."""
    graph = import_graph()
    cycles = import_cycles(graph)
    lines = [f"{', '.join(group)}: " + " -> ".join(c) + "\n    "
             + "\n    ".join(f"{a} -> {b}: {graph[a][b]}" for a, b in zip(c, c[1:])) for group, c in cycles]
    assert not cycles, f"{len(cycles)} group(s) of modules importing each other:\n" + "\n".join(lines)


def test_the_cycle_finder_finds_cycles():
    """The finder itself: a loop of three, a pair and a type-only pair are found; a chain is not."""
    graph = {"a": {"b": ""}, "b": {"c": ""}, "c": {"a": ""}, "d": {"e": ""}, "e": {"d": ""}, "f": {"a": ""}, "g": {}}
    assert import_cycles(graph) == [(["a", "b", "c"], ["a", "b", "c", "a"]), (["d", "e"], ["d", "e", "d"])]
    assert import_cycles({"x": {"y": ""}, "y": {}}) == []
    assert "planning.sim" in import_graph()["planning.bench"]       # a real edge is seen


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
