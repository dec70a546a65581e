"""The ``nutribench`` command line: a thin typer layer over the library, at the top of the house.

One module per command group: :mod:`~nutribench.cli.regimes` (``regimes list|check|generate``),
:mod:`~nutribench.cli.agents` (``baselines``, ``train``), :mod:`~nutribench.cli.run`
(``run``, ``status``), :mod:`~nutribench.cli.report` (``report``), :mod:`~nutribench.cli.evaluate` (``evaluate``), :mod:`~nutribench.cli.leaderboard`
(``leaderboard``), :mod:`~nutribench.cli.db` (``db copy``, ``db export``, ``db import``) and
:mod:`~nutribench.cli.bench` (``bench env|train|tune``), :mod:`~nutribench.cli.tune` (``tune``, ``tune status|best``); :mod:`~nutribench.cli.common`
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
    "jinja2",
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


#: Each command of the app: its name, the module and attribute of its function (a command) or
#: of its typer app (a group), in the order ``nutribench --help`` lists them.
COMMANDS: tuple[tuple[str, str], ...] = (
    ("regimes", "nutribench.cli.regimes:regimes_app"),
    ("baselines", "nutribench.cli.agents:baselines"),
    ("train", "nutribench.cli.agents:train_cmd"),
    ("run", "nutribench.cli.run:run_cmd"),
    ("status", "nutribench.cli.run:status_cmd"),
    ("report", "nutribench.cli.report:report_cmd"),
    ("compare", "nutribench.cli.compare:compare_cmd"),
    ("leaderboard", "nutribench.cli.leaderboard:leaderboard_cmd"),
    ("evaluate", "nutribench.cli.evaluate:evaluate_cmd"),
    ("db", "nutribench.cli.db:db_app"),
    ("bench", "nutribench.cli.bench:bench_app"),
    ("tune", "nutribench.cli.tune:tune_app"),
)


def build_app(only: str | None = None) -> typer.Typer:
    """The typer app with every command group (imports typer and the command modules); with
    ``only`` (a name of :data:`COMMANDS`), the app with that one command: what ``nutribench
    NAME ...`` runs, so that one command's start-up does not build (nor import) the others."""
    import importlib

    import typer

    app = typer.Typer(
        no_args_is_help=True,
        add_completion=False,
        rich_markup_mode=None,
        help="NutriRL: RL under delayed state transitions.",
    )

    def print_version(value: bool) -> None:
        if value:
            from nutribench import __version__

            typer.echo(f"nutribench {__version__}")
            raise typer.Exit()

    @app.callback()
    def options(
        version: bool = typer.Option(
            False, "--version", callback=print_version, is_eager=True, help="Print the version and exit."
        ),
    ) -> None:
        pass

    for name, where in COMMANDS:
        if only is None or name == only:
            module, attribute = where.split(":")
            target = getattr(importlib.import_module(module), attribute)
            if isinstance(target, typer.Typer):
                app.add_typer(target, name=name)
            else:
                app.command(name)(target)
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
    """The console script's entry point: the app, or one line naming the missing extra (status 2).
    ``nutribench --version`` needs no extra: it prints the installed version on the base install too."""
    if sys.argv[1:] == ["--version"]:
        from nutribench import __version__

        print(f"nutribench {__version__}")
        return
    missing = missing_experiment_modules()
    if missing:
        named = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        print(
            f"nutribench: the command line needs the experiments extra ({named} missing): {INSTALL_HINT}",
            file=sys.stderr,
        )
        sys.exit(2)
    name = sys.argv[1] if len(sys.argv) > 1 else None
    if name in dict(COMMANDS) and "app" not in globals():
        build_app(only=name)()
        return
    get_app()()
