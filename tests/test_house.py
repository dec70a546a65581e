"""The house's imports run one way: no circle between modules, and no room imports a room
above it (README "Architecture"). Every import is counted, including those inside
functions (the lazy imports that keep the CLI fast), because a lazy import upward is still
a dependency upward."""

from __future__ import annotations

import ast
from pathlib import Path

import nutribench

PACKAGE = Path(nutribench.__file__).parent

# Rooms from the bottom of the house to the top: a module may import its own room and the
# rooms below it (and those of its own floor). "nutribench" is the package's __init__
# (version, env registration). The store and the scheduler share a floor: the scheduler
# writes jobs through the store's tables, and importing an archive (store) asks the
# scheduler's job lifecycle whether a job is still running.
LAYERS: list[set[str]] = [
    {"nutribench", "errors", "clock", "provenance", "diagnostics", "safe_write", "stats", "engines"},
    {"config"},
    {"env"},
    {"agents", "baselines", "engine"},
    {"store", "scheduler"},
    {"report", "recorder"},
    {"bench", "tuning"},
    {"cli"},
]
LEVEL = {room: k for k, rooms in enumerate(LAYERS) for room in rooms}


def module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def room(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "nutribench"


def _facade_nodes(tree: ast.AST) -> set[int]:
    """The nodes inside the package root's ``__getattr__``: the front door that re-exports the
    public API lazily (``nutribench.Recorder``), not a room; its imports are not the root's."""
    return {
        id(n) for f in ast.walk(tree) if isinstance(f, ast.FunctionDef) and f.name == "__getattr__" for n in ast.walk(f)
    }


def import_graph() -> dict[str, set[str]]:
    """module -> the nutribench modules it imports (resolved to existing modules)."""
    files = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    graph: dict[str, set[str]] = {}
    for name, path in files.items():
        package = name if path.name == "__init__.py" else name.rpartition(".")[0]
        deps: set[str] = set()
        tree = ast.parse(path.read_text(), str(path))
        facade = _facade_nodes(tree) if name == "nutribench" else set()
        for node in ast.walk(tree):
            if id(node) in facade:
                continue
            targets: list[str] = []
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = package.split(".")[: len(package.split(".")) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                targets = [mod] + [f"{mod}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            deps |= {t for t in targets if t in files and t != name}
        graph[name] = deps
    return graph


def test_the_graph_is_read() -> None:
    graph = import_graph()
    assert "nutribench.cli" in graph and "nutribench.store.engine" in graph["nutribench.store.schema"]


def test_no_room_imports_a_room_above_it() -> None:
    upward = [
        f"{m} ({room(m)}) imports {d} ({room(d)})"
        for m, deps in import_graph().items()
        for d in sorted(deps)
        if LEVEL[room(d)] > LEVEL[room(m)]
    ]
    assert not upward, "\n".join(upward)


def test_every_room_has_a_level() -> None:
    assert {room(m) for m in import_graph()} <= set(LEVEL)


def test_no_import_circle() -> None:
    """Tarjan's strongly connected components; a package's __init__ re-exporting its
    submodules while they import their siblings through it counts as a circle too."""
    graph = import_graph()
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    circles: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                circles.append(sorted(component))

    for v in graph:
        if v not in index:
            visit(v)
    assert not circles, circles


MAX_LINES = 400


def test_no_module_over_400_lines_without_a_stated_reason() -> None:
    """Big rooms are split by what they hold; a module longer than MAX_LINES says why in its
    docstring ("Longer than 400 lines: ...")."""
    too_long = []
    for path in PACKAGE.rglob("*.py"):
        text = path.read_text()
        n = text.count("\n")
        doc = ast.get_docstring(ast.parse(text)) or ""
        if n > MAX_LINES and "Longer than 400 lines:" not in doc:
            too_long.append(f"{path.relative_to(PACKAGE.parent)}: {n} lines")
    assert not too_long, too_long
