"""The package as people install it: the base install is the environment alone (gymnasium,
numpy, pydantic), the ``experiments`` extra brings the command line and everything behind it,
and without that extra the ``nutribench`` command says so in one line. ``nutribench
--version`` prints the installed version.

These tests simulate a base install by blocking the extra's modules (``sys.modules[name] =
None`` makes ``import name`` fail as if it were not installed) in a fresh interpreter. The
real thing (a wheel built, installed alone and with the extra into fresh virtual
environments, its size bounded) is .ci/run's packaging step.
"""

from __future__ import annotations

import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import EXPERIMENT_MODULES, INSTALL_HINT, app

ROOT = Path(__file__).resolve().parents[1]
PYPROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))

#: Distribution name -> import name, where they differ
IMPORT_NAME = {"tomli-w": "tomli_w", "stable-baselines3": "stable_baselines3"}

#: What the environment may load from site-packages: the base dependencies and theirs
#: (_distutils_hack: setuptools' .pth hook, present in any venv with setuptools)
BASE_MODULES = {
    "gymnasium",
    "farama_notifications",
    "cloudpickle",
    "numpy",
    "pydantic",
    "pydantic_core",
    "annotated_types",
    "typing_extensions",
    "typing_inspection",
    "nutribench",
    "_distutils_hack",
}


def _names(requirements: list[str]) -> set[str]:
    out = set()
    for req in requirements:
        name = req.split(";")[0].split("[")[0]
        for sep in "<>=!~ ":
            name = name.split(sep)[0]
        out.add(name.strip().lower())
    return out


def _run_blocked(code: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    """``code`` in a fresh interpreter where no module of the experiments extra can be imported."""
    block = f"import sys\nfor _m in {sorted(EXPERIMENT_MODULES)!r}:\n    sys.modules[_m] = None\n"
    return subprocess.run(
        [sys.executable, "-c", block + code], cwd=cwd, capture_output=True, text=True, timeout=120, check=False
    )


def test_version_option_prints_the_installed_version() -> None:
    result = CliRunner().invoke(app, ["--version"])
    assert result.exit_code == 0, result.output
    assert result.output.strip() == f"nutribench {version('nutribench')}"


def test_version_option_is_in_the_help() -> None:
    result = CliRunner().invoke(app, ["--help"])
    assert result.exit_code == 0 and "--version" in result.output


def test_the_base_install_is_the_environment_alone() -> None:
    deps = PYPROJECT["project"]["dependencies"]
    assert _names(deps) == {"gymnasium", "numpy", "pydantic"}


def test_the_cli_checks_exactly_the_experiments_extra() -> None:
    extra = _names(PYPROJECT["project"]["optional-dependencies"]["experiments"])
    assert {IMPORT_NAME.get(n, n) for n in extra} == set(EXPERIMENT_MODULES)


def test_the_dev_extra_includes_the_experiments_extra() -> None:
    extras = PYPROJECT["project"]["optional-dependencies"]
    assert "nutribench[experiments]" in extras["dev"]
    assert "build" in _names(extras["dev"])


def test_the_console_script_is_main() -> None:
    """``main`` checks for the extra before anything imports it; the typer app cannot."""
    assert PYPROJECT["project"]["scripts"]["nutribench"] == "nutribench.cli:main"


def test_the_environment_runs_without_the_experiments_extra(tmp_path: Path) -> None:
    code = """
import sysconfig
import gymnasium
import nutribench

env = gymnasium.make(nutribench.ENV_ID)
env.reset(seed=0)
env.step(env.action_space.sample())
env = gymnasium.make("nutribench/NutriRL-run6-v0", render_mode="ansi")
env.reset(seed=1)
assert "step" in env.render()
vec = gymnasium.make_vec("nutribench/NutriRL-run3-v0", num_envs=3)
vec.reset(seed=0)
vec.step(vec.action_space.sample())
site = sysconfig.get_paths()["purelib"]
loaded = {n.partition(".")[0] for n, m in list(sys.modules.items()) if (getattr(m, "__file__", None) or "").startswith(site)}
print(" ".join(sorted(loaded)))
"""
    result = _run_blocked(code, tmp_path)
    assert result.returncode == 0, result.stderr
    loaded = set(result.stdout.split())
    assert loaded <= BASE_MODULES, f"the environment loaded {sorted(loaded - BASE_MODULES)}"


@pytest.mark.parametrize(
    "entry",
    [
        "sys.argv = ['nutribench', 'run', '--regimes', 'run0', '--algos', 'mc']\n"
        "from nutribench.cli import main\nmain()",
        "sys.argv = ['nutribench', 'run', '--version']\nfrom nutribench.cli import main\nmain()",
        "import runpy\nsys.argv = ['nutribench']\nrunpy.run_module('nutribench.cli', run_name='__main__')",
    ],
    ids=["run", "run --version", "python -m nutribench.cli"],
)
def test_without_the_extra_the_command_says_what_to_install(tmp_path: Path, entry: str) -> None:
    result = _run_blocked(entry, tmp_path)
    assert result.returncode == 2, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert INSTALL_HINT in lines[0] and "experiments extra (typer, " in lines[0]
    assert result.stdout == ""
    assert list(tmp_path.iterdir()) == []  # nothing written (no database)


@pytest.mark.parametrize(
    "entry",
    [
        "sys.argv = ['nutribench', '--version']\nfrom nutribench.cli import main\nmain()",
        "import runpy\nsys.argv = ['nutribench', '--version']\nrunpy.run_module('nutribench.cli', run_name='__main__')",
    ],
    ids=["nutribench --version", "python -m nutribench.cli --version"],
)
def test_version_works_without_the_extra(tmp_path: Path, entry: str) -> None:
    """docs/getting-started.md: `nutribench --version` prints the installed version, on the
    base install too (it exited 2 there, naming the extra)."""
    result = _run_blocked(entry, tmp_path)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"nutribench {version('nutribench')}" and result.stderr == ""


def test_gymnasiums_checker_passes_on_every_regime_without_the_extra(tmp_path: Path) -> None:
    """Gymnasium's check_env renders every mode of the metadata; rgb_array is drawn with numpy
    alone, so the base install passes it (it needed matplotlib), with no warning either."""
    code = """
import warnings
warnings.simplefilter("error")
import gymnasium as gym, nutribench
from gymnasium.utils.env_checker import check_env
ids = sorted(i for i in gym.registry if i.startswith("nutribench/"))
for i in ids:
    check_env(gym.make(i).unwrapped)
print(" ".join(ids))
"""
    result = _run_blocked(code, tmp_path)
    assert result.returncode == 0, result.stderr
    assert len(result.stdout.split()) == 8  # the seven regimes' ids and the generic one


def test_one_missing_module_is_named(tmp_path: Path) -> None:
    code = (
        "sys.modules['optuna'] = None\nsys.argv = ['nutribench', 'tune', '--help']\n"
        "from nutribench.cli import main\nmain()"
    )
    result = subprocess.run(
        [sys.executable, "-c", "import sys\n" + code], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 2
    assert result.stderr.strip() == (
        f"nutribench: the command line needs the experiments extra (optuna missing): {INSTALL_HINT}"
    )


def test_with_the_extra_main_runs_the_app(tmp_path: Path) -> None:
    result = subprocess.run(
        [sys.executable, "-m", "nutribench.cli", "--version"], cwd=tmp_path, capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == f"nutribench {version('nutribench')}"
