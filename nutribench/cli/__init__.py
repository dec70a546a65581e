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
"""

from __future__ import annotations

import typer

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


def main() -> None:  # pragma: no cover
    """The console script's entry point."""
    app()
