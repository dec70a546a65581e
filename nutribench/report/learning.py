"""The learning-curve figure (``nutribench report --fig 6``, alias ``--fig learning``): the
sample-efficiency view rliable users expect, from the evaluations during training
(``nutribench run --eval-every N``; the ``learning_curve`` view).

Per run (one job) and evaluation, its score is the share of the never -> planner gap it
closes on its validation days, as a run's score on its test days is
(:func:`~nutribench.report.scores.run_scores`, with the ``never`` and ``planner`` returns
stored with each validation day). Per regime, agent and training day: the IQM of the seeds'
scores and its 95 % interval over seeds (:func:`nutribench.stats.iqm_runs_ci`, the IQM's
interval of the aggregate figure, :mod:`nutribench.report.aggregate`). One panel per regime, one line
per agent. These are validation days, never the test days of the tables.
"""

from __future__ import annotations

from collections.abc import Sequence

import pandas as pd

from nutribench.report.aggregate import point_estimate
from nutribench.report.data import largest_budget_jobs
from nutribench.report.figure_parts import (
    FigureResult,
    agent_labels,
    budget_seeds_line,
    count_span,
    set_title,
    sort_regimes,
)
from nutribench.report.figures import GAP_LABEL, dress_panel, gap_axis, panel_grid, training_legend
from nutribench.report.palette import Palette, palette
from nutribench.report.palette import order as sort_algos
from nutribench.report.scores import DEFAULT_REPS, run_scores
from nutribench.stats import CONFIDENCE, iqm_runs_ci
from nutribench.stats import caption as interval_caption

CURVE_COLUMNS = ["regime", "algo", "train_day", "iqm", "lo", "hi", "seeds"]


def one_job_per_run(curve: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """Rows of ``learning_curve`` keeping one job per (regime, algo, seed): the one of the
    largest budget (then the newest); and a note per run that had others."""
    curve, left = largest_budget_jobs(curve)
    return curve, [f"{left} other jobs of the same runs (smaller budgets or older) left out"] if left else []


def learning_scores(curve: pd.DataFrame) -> pd.DataFrame:
    """Per run and evaluation: ``regime``, ``algo``, ``seed``, ``train_day``, ``score`` (the
    share of the gap its mean return closes over its validation days that day)."""
    parts = []
    for day, rows in curve.groupby("train_day", sort=True):
        refs = rows[["regime", "seed", "episode", "never", "planner"]].drop_duplicates(["regime", "seed", "episode"])
        scores = run_scores(rows, refs)
        parts.append(scores[["regime", "algo", "seed", "score"]].assign(train_day=int(day)))
    return pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=["regime", "algo", "seed", "score"])


def learning_points(scores: pd.DataFrame, reps: int = DEFAULT_REPS, seed: int = 0) -> pd.DataFrame:
    """Per regime, agent and training day: the IQM of the seeds' scores and its 95 %
    interval over seeds (NaN with one seed). Columns :data:`CURVE_COLUMNS`."""
    rows = []
    for (regime, algo, day), cell in scores.groupby(["regime", "algo", "train_day"], sort=True):
        runs = [cell["score"].dropna().to_numpy(dtype=float)]
        if not runs[0].size:
            continue
        lo, hi = iqm_runs_ci(runs, CONFIDENCE)[1:]  # NaN with one seed
        point = point_estimate("iqm", runs)
        rows.append(dict(regime=regime, algo=algo, train_day=int(day), iqm=point, lo=lo, hi=hi, seeds=runs[0].size))
    return pd.DataFrame(rows, columns=CURVE_COLUMNS)


def learning_curve_figure(
    curve: pd.DataFrame, colors: Palette | None = None, algos: Sequence[str] | None = None, reps: int = DEFAULT_REPS
) -> FigureResult:
    """The figure from rows of the ``learning_curve`` view (:func:`~nutribench.store.read_learning_curve`);
    ValueError when there are none (of ``algos``)."""
    if algos is not None:
        curve = curve[curve["algo"].isin(list(algos))]
    if curve.empty:
        raise ValueError("no evaluations during training (run with --eval-every N)")
    curve, notes = one_job_per_run(curve)
    points = learning_points(learning_scores(curve), reps)
    regimes, names = sort_regimes(points["regime"]), sort_algos(points["algo"])
    colors = colors or palette(names)
    legend = agent_labels(curve.drop_duplicates(["algo", "seed", "budget"])[["algo", "seed", "budget"]])
    fig, axes, ncols = panel_grid(len(regimes), 1.1, sharex=True)
    for k, (regime, ax) in enumerate(zip(regimes, axes)):
        for algo in names:
            line = points[(points["regime"] == regime) & (points["algo"] == algo)]
            if line.empty:
                continue
            c = colors.color(algo)
            ax.plot(
                line["train_day"], line["iqm"], color=c, lw=1.4, marker=colors.marker(algo), ms=4, label=legend[algo]
            )
            ax.fill_between(line["train_day"], line["lo"], line["hi"], color=c, alpha=0.2, lw=0)
        gap_axis(ax)
        dress_panel(ax, k, len(regimes), ncols, regime, "training day")
        if k % ncols:
            ax.set_ylabel("")
    training_legend(fig, list(axes), [legend[a] for a in names])
    n_days = count_span(curve.groupby("job_id")["episode"].nunique())
    caption = (
        f"{GAP_LABEL} on {n_days} validation days per evaluation (never the test days), "
        f"IQM over seeds with its 95 % interval over seeds ({interval_caption('iqm')})\n"
        f"{budget_seeds_line(curve)}"
    )
    set_title(fig, f"Learning curves: evaluation during training\n{caption}", notes)
    return FigureResult(fig, points, notes)
