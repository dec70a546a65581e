"""Writing a report's files: a figure as PNG (150 dpi) and PDF (:func:`write_figure`), a
table as Markdown, LaTeX and CSV (:func:`write_table`), and the trajectory view of one
evaluation episode (:func:`build_trajectory`: its steps read from the database, drawn with
:mod:`nutribench.report.trajectory` and written; what the database holds instead named in
the one-line error when it has no such episode). :mod:`nutribench.report.build` re-exports
all of it.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from nutribench.report.data import DbFile, ReportError, check_names, largest_budget_jobs
from nutribench.report.figures import FigureResult
from nutribench.report.palette import label as algo_label
from nutribench.report.tables import TableResult
from nutribench.safe_write import atomic_write

PNG_DPI = 150
#: The files :func:`write_table` writes: ``<stem>.<suffix>`` for each.
TABLE_SUFFIXES = ("md", "tex", "csv")


def write_atomically(path: Path, write: Callable[[Path], Any]) -> Path:
    """``write(tmp)`` to a unique temporary file beside ``path``, then renamed to ``path``, its
    folder made first (:func:`nutribench.safe_write.atomic_write`): a file is whole or absent,
    and a device node, a FIFO or a folder at ``path`` is never replaced. A failure to write (a
    full disk, a read-only folder) is a one-line :class:`ReportError`."""
    with atomic_write(path, error=ReportError, hint="give another --out or free the space") as tmp:
        write(tmp)
    return path


def write_figure(fig_result: FigureResult | Figure, out_dir: DbFile, stem: str) -> list[Path]:
    """Write ``<out_dir>/<stem>.png`` (150 dpi) and ``.pdf``; return both paths."""
    fig = fig_result.figure if isinstance(fig_result, FigureResult) else fig_result
    out = Path(out_dir)
    return [
        write_atomically(out / f"{stem}.png", lambda tmp: fig.savefig(tmp, dpi=PNG_DPI, format="png")),
        write_atomically(out / f"{stem}.pdf", lambda tmp: fig.savefig(tmp, format="pdf")),
    ]


def write_table(table_result: TableResult, out_dir: DbFile, stem: str) -> list[Path]:
    """Write ``<out_dir>/<stem>.md``, ``.tex`` and ``.csv``; return the three paths."""
    out = Path(out_dir)
    texts = dict(zip(TABLE_SUFFIXES, (table_result.to_markdown(), table_result.to_latex(), table_result.to_csv())))
    return [
        write_atomically(out / f"{stem}.{ext}", lambda tmp, text=text: tmp.write_text(text))
        for ext, text in texts.items()
    ]


def build_trajectory(
    db: DbFile, algo: str, regime: str, seed: int, episode: int = 0, out: DbFile = "reports"
) -> list[Path]:
    """The trajectory view of one evaluation episode, written as PNG and PDF.

    Uses the newest config versions and, if several jobs match, the largest budget.
    """
    from nutribench.env import RegimeDynamics
    from nutribench.report.trajectory import trajectory_figure
    from nutribench.store import open_store, read_eval_trajectories

    # both become the file's name and the regime is read from its file: names only
    check_names([regime], "regime", "--regime")
    check_names([algo], "agent config", "--algo")
    with open_store(db) as store:
        steps = read_eval_trajectories(
            store.engine, regimes=regime, algos=algo, seeds=seed, episode=episode, latest_only=True
        )
        if steps.empty:
            have = read_eval_trajectories(store.engine, latest_only=True)
            raise ReportError(
                f"no evaluation steps for {algo}/{regime} seed {seed} episode {episode} in {store.display}"
                + _available(have)
            )
    steps = largest_budget_jobs(steps, by=["seed"])[0]
    budget = int(steps["budget"].max())
    dynamics = RegimeDynamics(regime)
    ret = float(np.sum(steps["reward"].to_numpy(dtype=float)))
    title = f"{algo_label(algo)} on {regime}, seed {seed}, evaluation episode {episode} (budget {budget} episodes): return {ret:.2f}, {int(steps['action'].sum())} meals"
    fig = trajectory_figure(steps[["step", "food", "action", "C", "F", "P"]], dynamics, title=title)
    return write_figure(fig, out, f"trajectory_{regime}_{algo}_seed{seed}_ep{episode}")


#: Cells listed in "trajectory not found" before "... N more".
AVAILABLE_SHOWN = 4


def _available(steps: pd.DataFrame) -> str:
    if steps.empty:
        return " (the database holds no evaluation steps)"
    cells = steps[["algo", "regime", "seed"]].drop_duplicates()
    parts = [
        f"{a}/{r} seeds {','.join(map(str, sorted(g['seed'])))}" for (a, r), g in cells.groupby(["algo", "regime"])
    ]
    eps = sorted(steps["episode"].unique())
    shown = "; ".join(parts[:AVAILABLE_SHOWN]) + (
        f"; ... {len(parts) - AVAILABLE_SHOWN} more" if len(parts) > AVAILABLE_SHOWN else ""
    )
    return (
        f"; available: {shown} (episodes {eps[0]}-{eps[-1]}; all of them: "
        "nutribench status, or SELECT DISTINCT algo, regime, seed FROM episode_metrics WHERE phase = 'eval')"
    )
