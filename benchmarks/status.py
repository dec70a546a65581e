"""``python benchmarks/status.py``: how long ``nutribench status`` takes on a database holding
the full paper grid (7 regimes x 5 algorithms x 5 seeds x 5000 training days = 875,000
episode rows), filled with synthetic jobs (:mod:`nutribench.scheduler.synthetic`, no training).

A developer's script, not part of the installed package: run it from a checkout
(``python benchmarks/status.py --help`` for its options).
"""

from __future__ import annotations

import functools
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Annotated, Optional

import typer

from nutribench.bench.throughput import timings
from nutribench.cli.common import RepeatsOption, console, user_errors


def bench_status(db: str | None = None, repeats: int = 5, workers: int | None = None) -> dict:
    """Time ``status_table`` and ``nutribench status --json`` on a database holding the
    paper grid: ``db``, an existing database to time instead of building one (built in a
    temporary folder otherwise; that takes a few minutes). Medians over ``repeats``."""
    from nutribench.scheduler.status import status_table

    build_s = None
    if db is None:
        t0 = time.perf_counter()
        db = paper_grid_db(workers)
        build_s = time.perf_counter() - t0
    report = status_table(db)
    command = [sys.executable, "-m", "nutribench.cli", "status", "--json", "--db", db]
    return {
        "db": db,
        "jobs": sum(r.done + r.running + r.failed + r.pending for r in report.rows),
        "episode_rows": episode_rows(db),
        "db_mb": Path(db).stat().st_size / 2**20 if Path(db).exists() else None,
        "build_seconds": build_s,
        "status_table_s": statistics.median(timings(lambda: status_table(db), repeats)),
        "status_cli_s": statistics.median(
            timings(lambda: subprocess.run(command, check=True, capture_output=True), repeats)
        ),
    }


def paper_grid_db(workers: int | None = None) -> str:
    """A database in a new temporary folder holding the paper grid, run with the synthetic
    job (no sleep, no training); its path."""
    from nutribench.agents.registry import paper_names
    from nutribench.config import list_regimes
    from nutribench.scheduler.driver import GridSettings, run_grid
    from nutribench.scheduler.grid import PRESETS
    from nutribench.scheduler.synthetic import synthetic_job

    tmp = Path(tempfile.mkdtemp(prefix="nutribench-bench-status-"))
    db = str(tmp / "paper_grid.db")
    paper = PRESETS["paper"]
    run_grid(
        GridSettings(
            db,
            list_regimes(),
            paper_names(),
            paper.seeds,
            paper.episodes,
            workers=workers,
            job_fn=functools.partial(synthetic_job, seconds=0.0),  # without its per-episode sleep
            models_dir=tmp / "models",
            display=False,
        )
    )
    return db


def episode_rows(db: str) -> int:
    """The rows of the ``episode_metrics`` table of ``db``."""
    from sqlalchemy import func, select

    from nutribench.store.models import Episode
    from nutribench.store.schema import open_store

    store = open_store(db)
    try:
        with store.engine.connect() as conn:
            return conn.execute(select(func.count()).select_from(Episode)).scalar_one()
    finally:
        store.dispose()


def status_cmd(
    db: Annotated[
        Optional[str], typer.Option(help="time this database instead of building a synthetic paper grid")
    ] = None,
    repeats: RepeatsOption = 5,
) -> None:
    """Time `nutribench status` on a database holding the full paper grid (175 jobs,
    875,000 training-day rows of synthetic jobs; building it takes a few minutes)."""
    if db is None:
        console.print("building a synthetic paper-grid database (175 fake jobs x 5000 days) ...")
    r = bench_status(db, repeats=repeats)
    if r["build_seconds"] is not None:
        console.print(f"built {r['db']} in {r['build_seconds']:.0f} s")
    console.print(f"{r['jobs']} jobs, {r['episode_rows']:,} episode rows, {r['db_mb']:.0f} MB")
    console.print(
        f"status_table(): {r['status_table_s']:.3f} s   `nutribench status --json`: {r['status_cli_s']:.2f} s "
        f"(medians of {repeats}; the CLI figure includes Python start-up)"
    )


#: ``python benchmarks/status.py [OPTIONS]``: the command (``nutribench bench status`` until it
#: moved out of the installed package with the other developer's benchmarks)
app = typer.Typer(add_completion=False, rich_markup_mode=None)
app.command()(user_errors(status_cmd))

if __name__ == "__main__":
    app()
