"""The product apart from its research: no test imports a file under ``reports/`` (a finished
study's script is checked by the study's own folder, ``python -m pytest reports/<study>``), by
an import statement or by a loader that runs a file by its path; and nothing under
``reports/`` imports a private name of the package."""

from __future__ import annotations

import ast
import sys
from collections.abc import Iterator
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
TESTS = REPO / "tests"
REPORTS = REPO / "reports"
#: what runs a Python file by its path (``importlib.util``, ``runpy``, ``importlib.machinery``, ``imp``)
LOADERS = {"spec_from_file_location", "run_path", "SourceFileLoader", "SourcelessFileLoader", "load_source"}


def _study_modules() -> set[str]:
    """The names a file under ``reports/`` is imported by when its folder is on ``sys.path``
    (but a name a test module of ``tests/`` has, or the standard library's)."""
    own = {p.stem for p in TESTS.glob("*.py")}
    names = {p.stem for p in REPORTS.rglob("*.py") if "data" not in p.relative_to(REPORTS).parts}
    return names - own - set(sys.stdlib_module_names)


def offences(source: str, where: str, study_modules: set[str]) -> Iterator[str]:
    """Each import of a study's file in ``source`` (a test module's text)."""
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import | ast.ImportFrom):
            if isinstance(node, ast.ImportFrom) and node.level:
                continue  # a relative import: a package of the tests' own
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else [node.module or ""]
            for name in names:
                top = name.split(".")[0]
                if top in ("reports", "report_scripts") or top in study_modules:
                    yield f"{where}:{node.lineno} imports {name}"
        elif isinstance(node, ast.Call):
            func = node.func
            called = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
            if called in LOADERS and "reports" in ast.unparse(node).lower():
                yield f"{where}:{node.lineno} loads a file under reports/ ({called})"
            if called == "load_script":
                yield f"{where}:{node.lineno} loads a study's script (load_script)"


def test_no_test_imports_a_file_under_reports() -> None:
    modules = _study_modules()
    assert {"analyse", "without_memory", "trials", "positive_control"} <= modules  # the scan sees the studies
    found = [o for p in sorted(TESTS.rglob("*.py")) for o in offences(p.read_text(), p.name, modules)]
    assert not found, "tests import studies' files (move the check into the study's folder):\n" + "\n".join(found)


def test_the_scan_finds_each_way_of_importing_a_study() -> None:
    modules = _study_modules()
    bad = {
        "from report_scripts import load_script": 1,
        "import reports.tuned.analyse": 1,
        "from analyse import day_shares": 1,
        "import without_memory as w": 1,
        "import importlib.util\nimportlib.util.spec_from_file_location('a', ROOT / 'reports' / 'tuned' / 'analyse.py')": 1,
        "import runpy\nrunpy.run_path(str(REPORTS / 'ladder' / 'analyse.py'))": 1,
        "m = load_script('tuned', 'analyse')": 1,
        # reading a study's data, running the CLI, a file of the tests' own: none
        "import numpy as np\nnp.load(ROOT / 'reports' / 'paper' / 'data' / 'mc.npz')": 0,
        "from conftest import run_cli_args\nfrom .helpers import x\nimport json": 0,
        "import importlib.util\nimportlib.util.spec_from_file_location('page', tmp_path / 'page.py')": 0,
    }
    for source, n in bad.items():
        assert len(list(offences(source, "t.py", modules))) == n, source


def test_no_study_imports_a_private_name_of_the_package() -> None:
    """A study's script uses the package's public functions (a ``_name`` stays in its module)."""
    found = []
    for path in sorted(REPORTS.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("nutribench"):
                found += [
                    f"{path.relative_to(REPO)}:{node.lineno} {node.module}.{a.name}"
                    for a in node.names
                    if a.name.startswith("_")
                ]
    assert not found, "\n".join(found)


def test_the_moved_benches_options_say_where_they_went_in_one_line() -> None:
    """``bench train``'s cost benches moved to their studies' folders; the options they had say so."""
    from typer.testing import CliRunner

    from nutribench.cli import app

    cases = {
        ("--diagnostics-cost",): "reports/diagnostics_cost/README.md",
        ("--diagnostics-cost", "--lockstep", "--block", "10"): "reports/diagnostics_cost/README.md",
        ("--eval-every", "50"): "reports/eval_cost/README.md",
    }
    for extra, where in cases.items():
        res = CliRunner().invoke(app, ["bench", "train", "--algos", "mc", *extra])
        lines = res.output.strip().splitlines()
        assert res.exit_code == 2 and len(lines) == 1 and where in lines[0], res.output
        assert (REPO / where).is_file()
    import nutribench.bench as bench

    shipped = {p.stem for p in Path(bench.__file__).parent.glob("*.py")}
    assert not shipped & {"lockstep", "evalcost"}  # developer-only measurement code: with its study
