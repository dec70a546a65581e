"""One engine concept: the engines (sb3, batched, external) are named in nutribench/engines.py
only; every other module spells them through :class:`nutribench.engines.Engine`."""

from __future__ import annotations

import ast
from pathlib import Path

import nutribench
from nutribench.engines import ENGINES, TRAINING_ENGINES, Engine

PACKAGE = Path(nutribench.__file__).parent
HOME = PACKAGE / "engines.py"


def _engine_literals(path: Path) -> list[str]:
    """``"sb3"`` / ``"batched"`` anywhere, and ``"external"`` where it names an engine (the
    value of an ``"engine"`` key, or compared with something called engine): ``external`` is
    also an agent config's name (``algo = "external"``), which is not the engine."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and node.value in ("sb3", "batched"):
            found.append(f"{node.lineno}: {node.value!r}")
        elif isinstance(node, ast.Dict):
            for key, value in zip(node.keys, node.values):
                if (
                    isinstance(key, ast.Constant)
                    and key.value == "engine"
                    and isinstance(value, ast.Constant)
                    and value.value == "external"  # (a placeholder such as "-" names no engine)
                ):
                    found.append(f"{value.lineno}: engine {value.value!r}")
        elif isinstance(node, ast.Compare):
            parts = [node.left, *node.comparators]
            names = ast.unparse(node)
            if "engine" in names and any(isinstance(p, ast.Constant) and p.value == "external" for p in parts):
                found.append(f"{node.lineno}: {names}")
    return found


def test_engine_names_are_spelled_only_in_the_engines_module() -> None:
    found = {
        str(path.relative_to(PACKAGE.parent)): hits
        for path in sorted(PACKAGE.rglob("*.py"))
        if path != HOME and (hits := _engine_literals(path))
    }
    assert found == {}


def test_the_scan_finds_a_literal(tmp_path: Path) -> None:
    """The scan is not blind: each kind of spelling it refuses is found."""
    module = tmp_path / "m.py"
    module.write_text('E = "sb3"\nmeta = {"engine": "external"}\nif job["engine"] == "external":\n    pass\n')
    assert len(_engine_literals(module)) == 3


def test_engines_are_the_strings_stored_and_typed() -> None:
    assert [str(e) for e in ENGINES] == ["sb3", "batched", "external"]
    assert TRAINING_ENGINES == (Engine.SB3, Engine.BATCHED)
    assert Engine("batched") is Engine.BATCHED and Engine.SB3 == "sb3"
    assert f"{Engine.EXTERNAL}" == "external"
