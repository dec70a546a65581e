"""The report scripts (``reports/<folder>/<name>.py``) are files run by path, not an installed
package: the studies' own checks (``reports/<folder>/test_*.py``) load them the same way,
through :func:`load_script`."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path
from types import ModuleType

REPORTS = Path(__file__).resolve().parent


def load_script(folder: str, name: str) -> ModuleType:
    """``reports/<folder>/<name>.py`` as a module named ``<folder>_<name>``.

    The module is registered in :data:`sys.modules` before it runs, as an import would, so that
    a dataclass defined in it can look its module up.
    """
    path = REPORTS / folder / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"{folder}_{name}", path)
    if spec is None or spec.loader is None:
        raise FileNotFoundError(f"no report script at {path}")
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module
