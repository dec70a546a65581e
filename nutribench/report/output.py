"""Writing a report's files: a figure as PNG (150 dpi) and PDF (:func:`write_figure`), a
table as Markdown, LaTeX and CSV (:func:`write_table`), and the trajectory view of one
evaluation episode (:func:`build_trajectory`: its steps read from the database, drawn by
:func:`trajectory_figure` and written; what the database holds instead named in the one-line
error when it has no such episode). :mod:`nutribench.report.build` re-exports all of it.

The trajectory view (:func:`trajectory_figure`): one evaluation day, nutrients against
target, meals and their absorption curves. The picture that explains delayed transitions to
a newcomer.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from nutribench.config import NUTRIENTS
from nutribench.env import RegimeDynamics
from nutribench.report.data import DbFile, ReportError, check_names, largest_budget_jobs
from nutribench.report.figure_parts import wrap_text
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


# --------------------------------------------------------------------------- the trajectory view
NUTRIENT_COLORS = {"C": "#4c72b0", "F": "#dd8452", "P": "#55a868"}
NUTRIENT_NAMES = {"C": "carbohydrate", "F": "fat", "P": "protein"}
#: How a meal's name is written above the top panel, at the step it was eaten.
MEAL_NAME_STYLE = dict(rotation=90, va="bottom", ha="center", fontsize=7, color="0.3", clip_on=False)


def trajectory_figure(steps: pd.DataFrame, dynamics: RegimeDynamics, title: str = "") -> Figure:
    """``steps``: one evaluation episode, columns ``step`` (1..H), ``food`` (index offered),
    ``action`` (0/1), ``C``, ``F``, ``P`` (absorbed state after the step).

    Top: absorbed nutrients per step against the target, with the meals eaten marked.
    Bottom: each meal's absorption curve per nutrient (what it delivers at each step), so the
    lag between a decision and its effect is visible.
    """
    steps = steps.sort_values("step")
    meals = steps[steps["action"] == 1]
    fig = Figure(figsize=(10, 6.4), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 2])
    _absorbed_panel(top, steps, meals, dynamics)
    # outside the axes (any spot inside would cover the curves on some day) and under the
    # panels: at the upper right it lay beside the title, and covered a long title's end
    fig.legend(*top.get_legend_handles_labels(), loc="outside lower center", ncols=4, fontsize=8, frameon=False)
    top.grid(alpha=0.3)
    if title:
        fig.suptitle(wrap_text(title, fig, 10), fontsize=10)
    _absorption_panel(bottom, meals, dynamics)
    if meals.empty:  # a policy that never eats: say so instead of drawing two empty panels
        for ax in (top, bottom):
            ax.text(
                0.5, 0.5, "no meal eaten on this day", transform=ax.transAxes, ha="center", va="center", color="0.4"
            )
    H = dynamics.horizon
    bottom.set_ylabel("delivered per step\n(x daily target)")
    bottom.set_xlabel(f"step (1 step ~ 30 min; day = {H} steps)")
    bottom.set_xlim(0, H + 0.5)
    bottom.grid(alpha=0.3)
    bottom.set_title("absorption of each meal eaten (one curve per meal and nutrient)", fontsize=9, loc="left")
    return fig


def _absorbed_panel(ax, steps: pd.DataFrame, meals: pd.DataFrame, dynamics: RegimeDynamics) -> None:
    """The absorbed nutrients per step against the daily target, each meal marked and named
    above the axes, in a strip of its own (inside, the names covered the curves)."""
    x = np.concatenate([[0], steps["step"].to_numpy()])
    for n in NUTRIENTS:
        y = np.concatenate([[0.0], steps[n].to_numpy()])
        ax.step(x, y, where="post", color=NUTRIENT_COLORS[n], lw=1.8, label=f"{NUTRIENT_NAMES[n]} ({n})")
    ax.axhline(1.0, color="k", ls="--", lw=1, label="daily target")
    for t, food in zip(meals["step"].astype(int), meals["food"].astype(int)):
        ax.axvline(t - 0.5, color="0.6", lw=0.8, ls=":")
        name = dynamics.food_names[food].replace("_", " ")
        ax.text(t - 0.5, 1.01, name, transform=ax.get_xaxis_transform(), **MEAL_NAME_STYLE)
    ax.set_ylim(0, max(1.2, float(steps[list(NUTRIENTS)].to_numpy().max()) * 1.08))
    ax.set_ylabel("absorbed (x daily target)")


def _absorption_panel(ax, meals: pd.DataFrame, dynamics: RegimeDynamics) -> None:
    """Each meal's absorption curves: a meal eaten at step t delivers schedule[food, k] at step t + k."""
    for t, food in zip(meals["step"].astype(int), meals["food"].astype(int)):
        k = np.arange(0, dynamics.horizon - t + 1)
        for j, n in enumerate(NUTRIENTS):
            amount = dynamics.schedule[food, k, j]
            if amount.sum() <= 0:
                continue
            ax.plot(t + k, amount, color=NUTRIENT_COLORS[n], lw=1, alpha=0.85, marker="." if len(k) < 3 else None)
        ax.axvline(t - 0.5, color="0.6", lw=0.8, ls=":")
