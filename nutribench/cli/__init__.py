"""The ``nutribench`` command line: a thin typer layer over the library, at the top of the house.

One module per command group: :mod:`~nutribench.cli.regimes` (``regimes list|check|generate``),
:mod:`~nutribench.cli.agents` (``baselines``, ``train``), :mod:`~nutribench.cli.run`
(``run``, ``status``), :mod:`~nutribench.cli.report` (``report``), :mod:`~nutribench.cli.evaluate` (``evaluate``), :mod:`~nutribench.cli.leaderboard`
(``leaderboard``), :mod:`~nutribench.cli.db` (``db copy``, ``db export``, ``db import``) and
:mod:`~nutribench.cli.bench` (``bench env|train|learn|status|tune``), :mod:`~nutribench.cli.tune` (``tune``, ``tune status|best``); :mod:`~nutribench.cli.common`
holds what they share. Commands import the library they call when they run, so
``nutribench --help`` starts fast. Nothing below this package imports from it.

Errors a user can fix (any :class:`nutribench.errors.UserError`: bad config files, unknown
names, bad arguments, a database that cannot be used) print one line and exit with status
2; anything else is a bug and keeps its traceback.

The command line needs the ``experiments`` extra (typer, torch, SQLAlchemy, ...); the base
install is the environment alone. So this module imports none of it until the app is asked
for: ``app`` is built on first access, and :func:`main` (the console script) first checks
that the extra is installed, else prints one line naming it and exits with status 2.
"""

from __future__ import annotations

import sys
from importlib.util import find_spec
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import typer

#: The import names of the ``experiments`` extra (pyproject.toml; tests/test_packaging.py keeps
#: the two in sync), each needed by some command.
EXPERIMENT_MODULES = (
    "typer",
    "rich",
    "tomli_w",
    "matplotlib",
    "torch",
    "stable_baselines3",
    "sqlalchemy",
    "alembic",
    "pandas",
    "rliable",
    "scipy",
    "optuna",
)
#: What to install when the extra is missing
INSTALL_HINT = "pip install 'nutribench[experiments]'"


def _installed(name: str) -> bool:
    try:
        return find_spec(name) is not None
    except (ImportError, ValueError):  # a broken parent package, or a module without __spec__
        return False


def missing_experiment_modules() -> list[str]:
    """The modules of the ``experiments`` extra that cannot be imported here (found, not imported)."""
    return [name for name in EXPERIMENT_MODULES if not _installed(name)]


def build_app() -> typer.Typer:
    """The typer app with every command group (imports typer and the command modules)."""
    import typer

    from nutribench import __version__
    from nutribench.cli.agents import baselines, train_cmd
    from nutribench.cli.bench import bench_app
    from nutribench.cli.bench_engines import bench_engines_cmd
    from nutribench.cli.bench_tune import bench_tune_cmd
    from nutribench.cli.compare import compare_cmd
    from nutribench.cli.db import db_app
    from nutribench.cli.evaluate import evaluate_cmd
    from nutribench.cli.leaderboard import leaderboard_cmd
    from nutribench.cli.regimes import regimes_app
    from nutribench.cli.report import report_cmd
    from nutribench.cli.run import run_cmd, status_cmd
    from nutribench.cli.tune import tune_app

    app = typer.Typer(
        no_args_is_help=True,
        add_completion=False,
        rich_markup_mode=None,
        help="NutriRL: RL under delayed state transitions.",
    )

    def print_version(value: bool) -> None:
        if value:
            typer.echo(f"nutribench {__version__}")
            raise typer.Exit()

    @app.callback()
    def options(
        version: bool = typer.Option(
            False, "--version", callback=print_version, is_eager=True, help="Print the version and exit."
        ),
    ) -> None:
        pass

    app.add_typer(regimes_app, name="regimes")
    app.command("baselines")(baselines)
    app.command("train")(train_cmd)
    app.command("run")(run_cmd)
    app.command("status")(status_cmd)
    app.command("report")(report_cmd)
    app.command("compare")(compare_cmd)
    app.command("leaderboard")(leaderboard_cmd)
    app.command("evaluate")(evaluate_cmd)
    app.add_typer(db_app, name="db")
    bench_app.command("engines")(bench_engines_cmd)
    bench_app.command("tune")(bench_tune_cmd)
    app.add_typer(bench_app, name="bench")
    app.add_typer(tune_app, name="tune")
    return app


def get_app() -> typer.Typer:
    """The app, built on first use and kept."""
    app = globals().get("app")
    if app is None:
        app = globals()["app"] = build_app()
    return app


def __getattr__(name: str):
    """``nutribench.cli.app`` (built on first access, :func:`get_app`), so that importing this
    module needs nothing of the experiments extra."""
    if name == "app":
        return get_app()
    raise AttributeError(f"module 'nutribench.cli' has no attribute {name!r}")


def main() -> None:
    """The console script's entry point: the app, or one line naming the missing extra (status 2)."""
    missing = missing_experiment_modules()
    if missing:
        named = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        print(
            f"nutribench: the command line needs the experiments extra ({named} missing): {INSTALL_HINT}",
            file=sys.stderr,
        )
        sys.exit(2)
    get_app()()
