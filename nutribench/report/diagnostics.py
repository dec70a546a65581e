"""The training-diagnostics figure: what an agent's updates looked like while it learned.

:func:`diagnostics_figure` draws one panel per quantity of :mod:`nutribench.diagnostics` that
the rows hold (losses, KL, clip fraction, explained variance, gradient norm, learning rate,
epsilon, mean Q, return scale), one line per seed, against the training day (the update's
env steps / the horizon). Series longer than :data:`SMOOTH_ABOVE` points (MC, DDQN and SAC
record a row per day: 5000 in a paper job) are drawn as a centred rolling mean over
:data:`SMOOTH_SHARE` of the series, which the figure's title says. A panel whose values are
all positive and span more than two decades gets a log axis.

:func:`build_diagnostics` (``nutribench report --diagnostics --algo A --regime R``) reads the
``training_diagnostics`` view (newest config versions; per seed the job with the largest
budget, the newest if several) and writes ``diagnostics_<regime>_<algo>.png`` and ``.pdf``.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from nutribench.diagnostics import QUANTITIES
from nutribench.report.data import DbFile, ReportError, check_names, largest_budget_jobs
from nutribench.report.output import write_figure
from nutribench.report.palette import label as algo_label

#: Panel titles of the quantities.
TITLES: dict[str, str] = {
    "policy_loss": "policy loss",
    "value_loss": "value loss (SAC: critic, DDQN: TD)",
    "entropy_loss": "entropy loss (- entropy)",
    "approx_kl": "approximate KL",
    "clip_fraction": "clip fraction",
    "explained_variance": "explained variance",
    "grad_norm": "gradient norm (before clipping)",
    "learning_rate": "learning rate",
    "epsilon": "epsilon (exploration)",
    "q_mean": "mean Q",
    "actor_loss": "actor loss",
    "ent_coef": "entropy coefficient",
    "return_scale": "return scale (VecNormalize)",
}
SMOOTH_ABOVE = 200  # points per series drawn as they are
SMOOTH_SHARE = 0.02  # rolling window: this share of the series
FIGURE_COLUMNS = 3


def diagnostics_figure(rows: pd.DataFrame, horizon: int, title: str = "") -> Figure:
    """``rows``: one row per update, columns ``seed``, ``timestep`` and the quantities (NaN
    where absent). One panel per quantity present, one line per seed, x = training day."""
    present = [q for q in QUANTITIES if q in rows and rows[q].notna().any()]
    if not present:
        raise ValueError("no diagnostics quantity has a value")
    n_rows = math.ceil(len(present) / FIGURE_COLUMNS)
    fig = Figure(figsize=(4.2 * FIGURE_COLUMNS, 2.5 * n_rows + 0.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(n_rows, FIGURE_COLUMNS, sharex=True, squeeze=False)).ravel()
    seeds = sorted(rows["seed"].unique())
    colors = {s: f"C{k % 10}" for k, s in enumerate(seeds)}
    longest = int(rows.groupby("seed").size().max())
    window = max(1, round(SMOOTH_SHARE * longest)) if longest > SMOOTH_ABOVE else 1
    for ax, q in zip(axes, present):
        for seed in seeds:
            g = rows[(rows["seed"] == seed) & rows[q].notna()].sort_values("timestep")
            if g.empty:
                continue
            day = g["timestep"].to_numpy(dtype=float) / horizon
            y = g[q].astype(float)
            y = y.rolling(window, center=True, min_periods=1).mean() if window > 1 else y
            ax.plot(day, y, color=colors[seed], lw=1.1, label=f"seed {seed}")
        values = rows[q].dropna().to_numpy(dtype=float)
        if len(values) and values.min() > 0 and values.max() / values.min() > 100:
            ax.set_yscale("log")
        ax.set_title(TITLES.get(q, q), fontsize=9, loc="left")
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
    for ax in axes[len(present) :]:
        ax.set_visible(False)
    for ax in axes[max(0, len(present) - FIGURE_COLUMNS) : len(present)]:
        ax.set_xlabel("training day", fontsize=8)
        ax.xaxis.set_tick_params(labelbottom=True)
    fig.legend(*axes[0].get_legend_handles_labels(), loc="outside right upper", fontsize=8, frameon=False)
    how = f"rolling mean over {window} updates" if window > 1 else "one point per update"
    fig.suptitle(f"{title} ({how})" if title else how, fontsize=10)
    return fig


def _too_short(engine, algo: str, regime: str) -> str:
    """Why jobs of ``algo`` on ``regime`` have no diagnostics when they trained too few days
    to make an update (an off-policy agent learns only after ``learning_starts`` steps); "" else."""
    from sqlalchemy import select

    from nutribench.store import AgentConfig, Job, RegimeConfig

    with engine.connect() as conn:
        rows = conn.execute(
            select(Job.episodes, AgentConfig.body, RegimeConfig.body)
            .join(AgentConfig, AgentConfig.id == Job.agent_config_id)
            .join(RegimeConfig, RegimeConfig.id == Job.regime_id)
            .where(AgentConfig.name == algo, RegimeConfig.name == regime, Job.status == "done", Job.fake.is_(False))
        ).all()
    starts = [(int(d), int(a.get("learning_starts") or 0), int(r["reward"]["horizon"])) for d, a, r in rows]
    if not starts or any(days * h > ls for days, ls, h in starts):
        return ""
    days, ls, h = max(starts)
    return (
        f": its jobs trained {'/'.join(str(d) for d in sorted({d for d, _, _ in starts}))} days, and {algo} makes its "
        f"first update only after learning_starts = {ls} steps (day {ls // h}): no update, so no diagnostics; "
        "train it longer"
    )


def build_diagnostics(
    db: DbFile, algo: str, regime: str, seeds: list[int] | None = None, out: DbFile = "reports"
) -> list[Path]:
    """The diagnostics figure of ``algo`` on ``regime`` (all its seeds, or ``seeds``), written
    as PNG and PDF; a :class:`ReportError` (one line) when the database has none for it."""
    from sqlalchemy import select

    from nutribench.store import RegimeConfig, open_store, read_training_diagnostics

    check_names([regime], "regime", "--regime")
    check_names([algo], "agent config", "--algo")
    with open_store(db) as store:
        rows = read_training_diagnostics(store.engine, regimes=regime, algos=algo, seeds=seeds, latest_only=True)
        have = None if not rows.empty else read_training_diagnostics(store.engine, latest_only=True)
        why = _too_short(store.engine, algo, regime) if rows.empty else ""
        if not rows.empty:  # the day's length as the stored regime says (it may not be a file here)
            version = int(rows["regime_version"].max())
            with store.engine.connect() as conn:
                body = conn.execute(
                    select(RegimeConfig.body).where(RegimeConfig.name == regime, RegimeConfig.version == version)
                ).scalar_one()
            horizon = int(body["reward"]["horizon"])
    if rows.empty:
        which = f"{algo}/{regime}" + (f" seed {','.join(map(str, seeds))}" if seeds else "")
        if have is None or have.empty:
            where = " (the database holds none: jobs stored before schema revision 0005, external agents and dry runs have no diagnostics)"
        else:
            cells = have[["algo", "regime"]].drop_duplicates().sort_values(["algo", "regime"])
            shown = ", ".join(f"{a}/{r}" for a, r in cells.itertuples(index=False))
            where = f"; it has them for {shown}"
        raise ReportError(f"no training diagnostics for {which} in {store.display}{why or where}")
    rows = largest_budget_jobs(rows, by=["seed"])[0]  # per seed: the largest budget, the newest job if several
    budgets = sorted(rows["budget"].unique())
    engines = sorted(str(e) for e in rows["engine"].dropna().unique())
    title = (
        f"{algo_label(algo)} on {regime}: training diagnostics, {rows['seed'].nunique()} seed"
        f"{'s' if rows['seed'].nunique() != 1 else ''}, budget {'/'.join(map(str, budgets))} days"
        + (f", {'/'.join(engines)} engine" if engines else "")
    )
    fig = diagnostics_figure(rows, horizon, title=title)
    return write_figure(fig, out, f"diagnostics_{regime}_{algo}")
