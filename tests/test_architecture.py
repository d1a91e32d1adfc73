"""The house rules a newcomer relies on: the one-way flow, no import cycles, no module-level state
that functions change, a module map that names every module, and each package's public names
resolving."""
from __future__ import annotations

import ast
import importlib
import textwrap
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


def _short(name: str) -> str:
    """`shelfpick.planning.sim` -> `planning.sim`: the namespace every import goes through."""
    return name[len("shelfpick."):] if name.startswith("shelfpick.") else name


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
    names = {_short(n) for n in names}
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
                targets = [module(_short(a.name)) for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _short(node.module or "")
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


# methods that change the container they are called on
MUTATORS = frozenset({"append", "extend", "insert", "pop", "popitem", "remove", "clear", "update", "setdefault",
                      "add", "discard", "difference_update", "intersection_update", "symmetric_difference_update",
                      "appendleft", "extendleft", "popleft", "sort", "reverse", "__setitem__", "__delitem__"})


def _module_level_names(tree: ast.Module) -> set[str]:
    """Names a module binds itself at its top level (assignments, classes; not imports or functions),
    also inside top-level if/try/with blocks."""
    names: set[str] = set()
    todo = list(tree.body)
    while todo:
        st = todo.pop()
        if isinstance(st, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            for target in (st.targets if isinstance(st, ast.Assign) else [st.target]):
                names |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
        elif isinstance(st, ast.ClassDef):
            names.add(st.name)
        elif isinstance(st, (ast.If, ast.Try, ast.With)):
            todo += st.body + getattr(st, "orelse", []) + getattr(st, "finalbody", [])
            todo += [s for h in getattr(st, "handlers", []) for s in h.body]
    return names


def _local_names(fn: ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda) -> set[str]:
    """The names a function binds itself (parameters, assignments, imports, nested definitions),
    less those it declares `global`: these hide a module-level name of the same spelling."""
    a = fn.args
    out = {x.arg for x in a.posonlyargs + a.args + a.kwonlyargs} | {x.arg for x in (a.vararg, a.kwarg) if x}
    declared: set[str] = set()
    todo: list[ast.AST] = list(fn.body) if isinstance(fn.body, list) else [fn.body]
    while todo:
        n = todo.pop()
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            out.add(n.name)
            continue
        if isinstance(n, ast.Lambda):
            continue
        if isinstance(n, ast.Global):
            declared |= set(n.names)
        elif isinstance(n, ast.Name) and isinstance(n.ctx, (ast.Store, ast.Del)):
            out.add(n.id)
        elif isinstance(n, (ast.Import, ast.ImportFrom)):
            out |= {(x.asname or x.name).split(".")[0] for x in n.names}
        elif isinstance(n, ast.ExceptHandler) and n.name:
            out.add(n.name)
        todo += list(ast.iter_child_nodes(n))
    return out - declared


def _root(e: ast.expr) -> str | None:
    while isinstance(e, (ast.Attribute, ast.Subscript)):
        e = e.value
    return e.id if isinstance(e, ast.Name) else None


def module_state_changes(path: Path) -> list[str]:
    """Where a function changes module-level state of its own module: a `global` statement, or an
    item or attribute set or deleted on, or a mutating method (`MUTATORS`) called on, a name the
    module binds at its top level and the function does not hide (`X[k] = v`, `X.a = v`,
    `X.append(v)`, `X.cache.update(...)`). Module-level code itself (building a table at import) is
    not a change; nor is another module's state (an imported name), nor an object's own methods
    changing it (`self`)."""
    tree = ast.parse(path.read_text())
    module_names = _module_level_names(tree)
    shown = path.relative_to(ROOT) if path.is_relative_to(ROOT) else path
    out: list[str] = []

    def scan(node: ast.AST, hidden: set[str], where: str) -> None:
        for ch in ast.iter_child_nodes(node):
            if isinstance(ch, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                name = getattr(ch, "name", "<lambda>")
                scan(ch, hidden | _local_names(ch), f"{where}.{name}" if where else name)
                continue
            what = None
            if where and isinstance(ch, ast.Global):
                what = "global " + ", ".join(ch.names)
            elif where and isinstance(ch, (ast.Subscript, ast.Attribute)) and isinstance(ch.ctx, (ast.Store, ast.Del)):
                if _root(ch) in module_names - hidden:
                    what = ast.unparse(ch) + (" set" if isinstance(ch.ctx, ast.Store) else " deleted")
            elif (where and isinstance(ch, ast.Call) and isinstance(ch.func, ast.Attribute)
                  and ch.func.attr in MUTATORS and _root(ch.func.value) in module_names - hidden):
                what = ast.unparse(ch.func) + "(...)"
            if what:
                out.append(f"{shown}:{ch.lineno} in {where}: {what}")
            scan(ch, hidden, where)

    scan(tree, set(), "")
    return out


def test_no_function_changes_module_level_state():
    """State that changes belongs to an object somebody creates and owns (a pool, a store, a guard),
    not to a module: module globals are shared by every caller, thread and test in the process."""
    found = [hit for path in _modules().values() for hit in module_state_changes(path)]
    assert not found, "module-level state changed from functions:\n" + "\n".join(found)


def test_the_state_finder_finds_changes(tmp_path):
    """The finder itself, on a small module: globals, items, attributes and mutating calls on module
    names are found, also in a nested function; a parameter or local of the same name is not."""
    src = tmp_path / "m.py"
    src.write_text(textwrap.dedent("""
        import os
        CACHE = {}
        SEEN: list = []
        class Registry:
            items = {}
        COUNT = 0
        CACHE["built at import"] = 1
        def bump():
            global COUNT
            COUNT += 1
        def remember(k, v):
            CACHE[k] = v
            Registry.items.update({k: v})
            def inner():
                SEEN.append(k)
            return inner
        def fine(CACHE, v):
            CACHE[0] = v
            seen = []
            seen.append(v)
            os.environ.setdefault("X", "1")
            return Registry().items.get(v)
    """))
    hits = [h.split(" in ", 1)[1] for h in module_state_changes(src)]
    assert hits == ["bump: global COUNT", "remember: CACHE[k] set", "remember: Registry.items.update(...)",
                    "remember.inner: SEEN.append(...)"]


def test_the_module_map_names_every_module():
    doc = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    missing = [m for m in _modules() if not m.endswith("__init__") and f"`{m.rsplit('.', 1)[1]}`" not in doc]
    assert not missing, f"docs/ARCHITECTURE.md does not name {missing}"


@pytest.mark.parametrize("pkg", PACKAGES)
def test_each_package_names_its_public_api(pkg):
    module = importlib.import_module(f"shelfpick.{pkg}")
    assert module.__doc__
    for name in getattr(module, "__all__", ()):
        assert getattr(module, name) is not None
    if pkg != "robotsim":
        assert module.__all__


def test_every_import_goes_through_the_shelfpick_namespace():
    """Installed, the packages exist only as `shelfpick.X`: a bare `import planning` would find another
    project's package of that name (PyPI has `console`, `planning`, `perception`, `static`) or none."""
    bare = []
    for folder in (*PACKAGES, "tests", "benchmarks", "examples", "static"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text())):
                names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                         [node.module] if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module
                         else [])
                bare += [f"{path.relative_to(ROOT)}:{node.lineno} {n}" for n in names
                         if n.split(".")[0] in (*PACKAGES, "static")]
    assert not bare, "imports outside the shelfpick namespace: " + ", ".join(bare)


TOOLING = ("perception.training", "perception.evaluation")   # what trains and measures perception


def tooling_in_runtime(root: Path) -> list[str]:
    """What breaks the split between what ships to a robot cell and what trains and measures
    perception: a train_* or bench* module left at perception/'s top level, and a module outside
    `TOOLING` that imports it when it loads (an import inside a function, run by a subcommand, is fine)."""
    found = [f"perception/{f.name}: training or measuring at perception's top level"
             for f in sorted((root / "perception").glob("*.py")) if f.name.startswith(("train_", "bench"))]
    for pkg in PACKAGES:
        for f in sorted((root / pkg).rglob("*.py")):
            mod = ".".join(f.relative_to(root).with_suffix("").parts)
            if mod.startswith(TOOLING):
                continue
            tree = ast.parse(f.read_text())
            in_function = {id(n) for node in ast.walk(tree) if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef))
                           for n in ast.walk(node)}
            for node in ast.walk(tree):
                if id(node) in in_function or not isinstance(node, (ast.Import, ast.ImportFrom)):
                    continue
                names = ([a.name for a in node.names] if isinstance(node, ast.Import) else
                         [f"{node.module}.{a.name}" for a in node.names] if node.module and node.level == 0 else [])
                found += [f"{f.relative_to(root)}:{node.lineno} imports {n} at module level" for n in map(_short, names)
                          if any(n == t or n.startswith(t + ".") for t in TOOLING)]
    return found


def test_the_runtime_does_not_load_training_or_measuring():
    """perception/training and perception/evaluation are apart from the runtime: nothing else loads them
    at import (the `train-seg` and `perceive-bench` subcommands import them when run)."""
    found = tooling_in_runtime(ROOT)
    assert not found, "\n".join(found)


def test_the_tooling_finder_finds_misplaced_modules(tmp_path):
    """The finder itself: a bench module at the top, a runtime module importing training at load are
    found; an import inside a subcommand's run and imports inside the tooling packages are not."""
    for pkg in PACKAGES:
        (tmp_path / pkg).mkdir()
    (tmp_path / "perception" / "training").mkdir()
    (tmp_path / "perception" / "bench_scenes.py").write_text("")
    (tmp_path / "perception" / "pipeline.py").write_text("from shelfpick.perception import training\n")
    (tmp_path / "perception" / "cmd_x.py").write_text("def run():\n    from shelfpick.perception.training import yolo\n")
    (tmp_path / "perception" / "training" / "yolo.py").write_text("import shelfpick.perception.evaluation.truth\n")
    (tmp_path / "console" / "cli.py").write_text("import shelfpick.perception.evaluation.bench as b\n")
    assert tooling_in_runtime(tmp_path) == [
        "perception/bench_scenes.py: training or measuring at perception's top level",
        "perception/pipeline.py:1 imports perception.training at module level",
        "console/cli.py:1 imports perception.evaluation.bench at module level"]


def test_every_package_folder_is_in_the_wheel():
    """pyproject.toml lists the packages by hand: a subpackage left off it (perception/training) is in a
    checkout and missing from the installed wheel."""
    tomllib = pytest.importorskip("tomllib")
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    folders = {"shelfpick." + ".".join(f.parent.relative_to(ROOT).parts)
               for pkg in PACKAGES for f in (ROOT / pkg).rglob("__init__.py")}
    assert folders <= listed, f"not in pyproject.toml's packages: {sorted(folders - listed)}"


# The console's rooms (issue 34) and which other rooms each may import. The console's top holds only the
# command line (cli, cmd_*) and what every room reads (cell, sources).
CONSOLE_ROOMS = {"store": set(), "robot": set(), "workflow": {"store", "robot"},
                 "web": {"store", "robot", "workflow"}}
CONSOLE_TOP = {"__init__", "cli", "cell", "sources"}


def console_layout(console: Path) -> list[str]:
    """What puts the console folder `console` out of its rooms: a room that is no package, a module at
    the top that is neither the command line nor a shared piece, a module named by a room's prefix."""
    out = [f"console/{room}/ is not a package" for room in CONSOLE_ROOMS if not (console / room / "__init__.py").exists()]
    for f in sorted(console.rglob("*.py")):
        rel = f.relative_to(console)
        if len(rel.parts) == 1 and f.stem not in CONSOLE_TOP and not f.stem.startswith("cmd_"):
            out.append(f"console/{rel}: at the top, in no room")
        if any(f.stem.startswith(room + "_") for room in CONSOLE_ROOMS):
            out.append(f"console/{rel}: named by a room's prefix")
    return out


def test_the_console_is_in_rooms():
    found = console_layout(ROOT / "console")
    assert not found, "\n".join(found)


def test_the_console_rooms_import_one_way():
    """web -> workflow -> robot, store: a room imports only the rooms below it (and the top's cell and
    sources), counting every import as the cycle check does."""
    def room(mod: str) -> str | None:
        parts = mod.split(".")
        return parts[1] if parts[0] == "console" and len(parts) > 2 and parts[1] in CONSOLE_ROOMS else None
    wrong = [f"{a} -> {b}: {where}" for a, edges in import_graph().items() if room(a)
             for b, where in edges.items() if room(b) not in (None, room(a)) and room(b) not in CONSOLE_ROOMS[room(a)]]
    assert not wrong, "\n".join(wrong)


def test_the_layout_finder_finds_a_flat_console(tmp_path):
    """The finder itself, on a flat console of the old kind: the missing rooms, the stray top modules and
    the prefixed names are all found; the command line and the shared pieces are not."""
    for name in ("__init__", "cli", "cmd_console", "cell", "sources", "app", "robot_tcp", "store_schema"):
        (tmp_path / f"{name}.py").write_text("")
    (tmp_path / "workflow").mkdir()
    (tmp_path / "workflow" / "__init__.py").write_text("")
    (tmp_path / "workflow" / "workflow_core.py").write_text("")
    assert console_layout(tmp_path) == [
        "console/store/ is not a package", "console/robot/ is not a package", "console/web/ is not a package",
        "console/app.py: at the top, in no room", "console/robot_tcp.py: at the top, in no room",
        "console/robot_tcp.py: named by a room's prefix", "console/store_schema.py: at the top, in no room",
        "console/store_schema.py: named by a room's prefix", "console/workflow/workflow_core.py: named by a room's prefix"]
