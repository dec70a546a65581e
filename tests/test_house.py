"""The house's imports run one way: no circle between modules, and no room imports a room
above it (README "Architecture"). Every import is counted, including those inside
functions (the lazy imports that keep the CLI fast), because a lazy import upward is still
a dependency upward. And a module is one idea, not a length: no module reaches into
another's private names (in place of a line cap, which got modules cut apart by length and
then reaching into each other)."""

from __future__ import annotations

import ast
from pathlib import Path

import nutribench

PACKAGE = Path(nutribench.__file__).parent

# Rooms from the bottom of the house to the top: a module may import its own room and the
# rooms below it (and those of its own floor). "nutribench" is the package's __init__
# (version, env registration). The scheduler writes jobs through the store's tables; the
# rule of what state a job is in (job_state) is the store's, so importing an archive asks it
# without going up to the scheduler.
LAYERS: list[set[str]] = [
    {"nutribench", "errors", "clock", "provenance", "diagnostics", "safe_write", "stats", "engines"},
    {"config"},
    {"env"},
    {"agents", "baselines", "engine"},
    {"store"},
    {"scheduler"},
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


def private_imports(package: Path) -> list[str]:
    """Each use, in a module of ``package``, of a private name (one leading underscore) of
    another module of the same package: ``from x import _y``, and ``x._y`` where ``x`` was
    imported as a module or name of the package (``import p.x as x``, ``from p import x``).
    A name another module needs is public (no underscore, a docstring), or the two modules
    are one idea and one module; dunders (``__version__``) are not private."""
    top = package.name
    found: list[str] = []
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
        tree = ast.parse(path.read_text(), str(path))
        where = path.relative_to(package.parent)
        bound: dict[str, str] = {}  # local name -> the package's module or name it stands for
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if node.level:
                    base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                    mod = ".".join(base + ([node.module] if node.module else []))
                else:
                    mod = node.module or ""
                if mod.split(".")[0] != top:
                    continue
                for a in node.names:
                    if _private(a.name) and mod != name:
                        found.append(f"{where}:{node.lineno}: from {mod} import {a.name}")
                    bound[a.asname or a.name] = f"{mod}.{a.name}"
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.split(".")[0] == top:
                        bound[a.asname or a.name.split(".")[0]] = a.name if a.asname else top
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Attribute)
                and _private(node.attr)
                and isinstance(node.value, ast.Name)
                and node.value.id in bound
                and bound[node.value.id] != name
            ):
                found.append(f"{where}:{node.lineno}: {node.value.id}.{node.attr} ({bound[node.value.id]})")
    return found


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


def test_no_module_imports_another_modules_private_names() -> None:
    """A ``_name`` stays in its module (DESIGN.md): a module is one idea, so one that needs
    another's private name either is that idea (one module) or the name is public."""
    found = private_imports(PACKAGE)
    assert not found, "\n".join(found)


def test_private_imports_are_found(tmp_path: Path) -> None:
    """The check above can fail: a planted package with each form of reaching in is caught,
    and its legitimate imports (public names, dunders, its own names, other packages) are not."""
    pkg = tmp_path / "planted"
    (pkg / "sub").mkdir(parents=True)
    (pkg / "__init__.py").write_text('__version__ = "1"\n')
    (pkg / "sub" / "__init__.py").write_text("")
    (pkg / "a.py").write_text("_secret = 1\npublic = 2\n\n\ndef _helper():\n    return _secret\n")
    (pkg / "sub" / "b.py").write_text(
        "import os\n"
        "from os import _exit\n"
        "from planted import __version__\n"
        "from planted.a import _secret, public\n"
        "from .. import a\n"
        "from ..a import _helper\n"
        "import planted.a as aa\n"
        "\n\ndef f():\n"
        "    from planted.a import _helper as h\n"
        "    return a._helper(), aa._secret, os._exit, h, public, _exit\n"
    )
    found = private_imports(pkg)
    assert sorted(line.split(": ", 1)[1] for line in found) == [
        "a._helper (planted.a)",
        "aa._secret (planted.a)",
        "from planted.a import _helper",
        "from planted.a import _helper",
        "from planted.a import _secret",
    ], found
    assert all(line.startswith("planted/sub/b.py:") for line in found)


#: public top-level names that several modules define on purpose, each with its reason
SAME_NAME_ON_PURPOSE: dict[str, str] = {
    "ALGORITHM": "each built-in algorithm's module holds its registry entry under this name: the registry "
    "scans nutribench/agents/builtin/ for it (nutribench.agents.registry.builtin_algorithms)",
}
#: names still defined twice, in modules another change is rewriting as this list is written
#: (bench/, the CLI, the engine names): to be renamed or said once
#: there, and then struck from this list. It only shrinks: a new name defined twice fails.
NOT_YET_ONE_NAME: dict[str, str] = {}


def top_level_names(package: Path) -> dict[str, list[str]]:
    """Each public name (no leading underscore) a module of ``package`` defines at its top
    level (a class, a function, an assigned or annotated name), and the modules defining it."""
    found: dict[str, list[str]] = {}
    for path in sorted(package.rglob("*.py")):
        parts = path.relative_to(package.parent).with_suffix("").parts
        module = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        tree = ast.parse(path.read_text(), str(path))
        names: set[str] = set()
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                names.add(node.name)
            elif isinstance(node, ast.Assign):
                names.update(t.id for t in node.targets if isinstance(t, ast.Name))
            elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
                names.add(node.target.id)
        for name in names - {"__all__"}:
            if not name.startswith("_"):
                found.setdefault(name, []).append(module)
    return found


def test_each_public_name_means_one_thing() -> None:
    """No public top-level name is defined in two modules of the package (one name, one
    thing: a reader of ``Algorithm`` or ``load_model`` knows which is meant); a name that
    several modules must define is listed, with its reason, in :data:`SAME_NAME_ON_PURPOSE`."""
    twice = {n: m for n, m in top_level_names(PACKAGE).items() if len(m) > 1}
    new = {n: m for n, m in twice.items() if n not in SAME_NAME_ON_PURPOSE and n not in NOT_YET_ONE_NAME}
    assert not new, "\n".join(f"{n}: {', '.join(m)}" for n, m in sorted(new.items()))
    done = sorted(set(NOT_YET_ONE_NAME) - set(twice))
    assert not done, f"now defined once, strike from NOT_YET_ONE_NAME: {done}"


def test_names_defined_twice_are_found(tmp_path: Path) -> None:
    """The check above can fail: two planted modules sharing a class, a function and a
    constant are caught; private names and ``__all__`` are not."""
    pkg = tmp_path / "planted"
    pkg.mkdir()
    (pkg / "a.py").write_text("class Thing: ...\n\n\ndef load(): ...\n\n\nLIMIT = 1\n_own = 1\n__all__ = []\n")
    (pkg / "b.py").write_text("Thing = int\nLIMIT: int = 2\n\n\ndef load(): ...\n\n\n_own = 2\n__all__ = []\n")
    shared = {n: m for n, m in top_level_names(pkg).items() if len(m) > 1}
    assert sorted(shared) == ["LIMIT", "Thing", "load"], shared


def test_the_batched_engine_does_not_reuse_sb3_class_names() -> None:
    """A class of the batched engine is never named as one of Stable-Baselines3's (``PPO``,
    ``SAC``, ``OnPolicyAlgorithm``...): ``from stable_baselines3 import PPO`` and the engine's
    class are told apart by name."""
    import stable_baselines3

    sb3_root = Path(stable_baselines3.__file__).parent
    sb3_names = set(top_level_names(sb3_root))
    ours = set(top_level_names(PACKAGE / "engine"))
    assert not ours & sb3_names, sorted(ours & sb3_names)
