"""Figure builders: pure functions from a DataFrame of episode metrics to a matplotlib Figure.

Input columns (those of the ``episode_metrics`` view): ``regime``, ``algo``, ``seed``,
``phase`` ("train" / "eval"), ``episode`` and the metric columns (``return``, ``foods``,
``final_distance``, ``overshoot_ratio``). Each builder returns a :class:`FigureResult`
holding the Figure and the exact numbers it drew, so tests (and curious readers) can
check them without parsing pixels.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

ALGO_ORDER = ["mc", "ddqn", "ppo", "sac", "gru_ppo"]
ALGO_LABELS = {"mc": "MC", "ddqn": "DDQN", "ppo": "PPO", "sac": "SAC", "gru_ppo": "GRU-PPO"}
ALGO_COLORS = {"mc": "#8c564b", "ddqn": "#1f77b4", "ppo": "#2ca02c", "sac": "#d62728", "gru_ppo": "#9467bd"}
METRIC_LABELS = {
    "return": "episodic return",
    "foods": "foods consumed",
    "final_distance": "final distance to target |s_H - T|_1",
    "overshoot_ratio": "overshoot ratio",
}
POLICY_STYLES = {
    "never": dict(color="0.45", ls=":", marker="x"),
    "random": dict(color="0.65", ls="-.", marker="."),
    "always": dict(color="0.75", ls="--", marker="+"),
    "planner": dict(color="k", ls="-", marker="*"),
}
EVAL_PANELS = ["return", "final_distance", "foods", "overshoot_ratio"]


@dataclass
class FigureResult:
    figure: Figure
    data: pd.DataFrame  # what was drawn: one row per (panel, line, x)
    notes: list[str] = field(default_factory=list)


def regime_index(name: str) -> int | None:
    m = re.fullmatch(r"run(\d+)", str(name))
    return int(m.group(1)) if m else None


def sort_regimes(names) -> list[str]:
    return sorted(set(names), key=lambda r: (regime_index(r) is None, regime_index(r) or 0, str(r)))


def sort_algos(names) -> list[str]:
    return sorted(set(names), key=lambda a: (ALGO_ORDER.index(a) if a in ALGO_ORDER else len(ALGO_ORDER), str(a)))


def algo_label(a: str) -> str:
    return ALGO_LABELS.get(a, a)


def algo_color(a: str, i: int) -> str:
    return ALGO_COLORS.get(a, f"C{i % 10}")


def default_window(n_episodes: int) -> int:
    """Smoothing window: ~2 % of the episodes, at least 1, at most 100."""
    return int(min(100, max(1, round(n_episodes / 50))))


def _seed_band(curves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error across seeds (rows); SE is NaN with one seed."""
    mean = np.nanmean(curves, axis=0)
    if curves.shape[0] < 2:
        return mean, np.full_like(mean, np.nan)
    n = np.sum(~np.isnan(curves), axis=0)
    se = np.nanstd(curves, axis=0, ddof=1) / np.sqrt(np.maximum(n, 1))
    return mean, se


def training_curves(
    df: pd.DataFrame,
    metric: str = "return",
    window: int | None = None,
    best_line: bool = True,
    title: str | None = None,
) -> FigureResult:
    """Figures 1 and 2: a training metric per episode, one panel per regime present, one line
    per algorithm (mean over seeds of the per-seed moving average, shaded standard error
    across seeds), and a dashed line at the best smoothed value of the panel."""
    train = df[df["phase"] == "train"]
    if train.empty:
        raise ValueError("no training episodes to plot")
    regimes = sort_regimes(train["regime"])
    algos = sort_algos(train["algo"])
    if window is None:
        window = default_window(int(train["episode"].max()) + 1)
    ncols = min(4, len(regimes))
    nrows = int(np.ceil(len(regimes) / ncols))
    fig = Figure(figsize=(4.2 * ncols, 3.2 * nrows + 0.9), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=True)
    rows = []
    for k, regime in enumerate(regimes):
        ax = axes.flat[k]
        sub = train[train["regime"] == regime]
        best = -np.inf
        for i, algo in enumerate(algos):
            cell = sub[sub["algo"] == algo]
            if cell.empty:
                continue
            wide = cell.pivot_table(index="seed", columns="episode", values=metric, aggfunc="mean").sort_index(axis=1)
            smoothed = wide.T.rolling(window, min_periods=1).mean().T.to_numpy()
            mean, se = _seed_band(smoothed)
            x = wide.columns.to_numpy()
            ax.plot(x, mean, color=algo_color(algo, i), lw=1.4, label=algo_label(algo))
            if not np.all(np.isnan(se)):
                ax.fill_between(x, mean - se, mean + se, color=algo_color(algo, i), alpha=0.2, lw=0)
            best = max(best, float(np.nanmax(mean)))
            rows.append(pd.DataFrame({"regime": regime, "algo": algo, "episode": x, "mean": mean, "sem": se, "n_seeds": wide.shape[0]}))
        if best_line and np.isfinite(best):
            ax.axhline(best, color="k", ls="--", lw=0.9, label="best (smoothed)")
        ax.set_title(f"{regime}", fontsize=10)
        ax.grid(alpha=0.3)
        if k % ncols == 0:
            ax.set_ylabel(METRIC_LABELS.get(metric, metric))
        if k >= len(regimes) - ncols:
            ax.set_xlabel("training episode")
    for ax in list(axes.flat)[len(regimes) :]:
        ax.set_visible(False)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    for ax in list(axes.flat)[1 : len(regimes)]:
        for h, lab in zip(*ax.get_legend_handles_labels()):
            if lab not in labels:
                handles.append(h)
                labels.append(lab)
    fig.legend(handles, labels, loc="outside lower center", ncols=min(6, len(labels)), fontsize=9, frameon=False)
    notes = _missing_note(regimes, algos, train)
    n_seeds = train.groupby(["regime", "algo"])["seed"].nunique()
    caption = f"mean over seeds ({n_seeds.min()}-{n_seeds.max()} per line) of a {window}-episode moving average; band = standard error across seeds"
    fig.suptitle((title or f"Training {METRIC_LABELS.get(metric, metric)}") + f"\n{caption}", fontsize=10)
    if notes:
        fig.text(0.99, 0.005, "; ".join(notes), ha="right", va="bottom", fontsize=7, color="0.3")
    return FigureResult(fig, pd.concat(rows, ignore_index=True), notes)


def _symlog_return_axis(ax) -> None:
    """Returns span -500 (always eat) to ~-35 (planner): a symmetric-log axis keeps the
    learners readable next to the references, with plain-number ticks."""
    from matplotlib.ticker import FixedLocator, ScalarFormatter

    lo, hi = ax.get_ylim()
    ax.set_yscale("symlog", linthresh=20, linscale=0.5)
    ticks = [t for t in (-1000, -500, -300, -200, -100, -50, -30, -20, 0, 20) if lo <= t <= hi]
    ax.yaxis.set_major_locator(FixedLocator(ticks))
    ax.yaxis.set_major_formatter(ScalarFormatter())
    ax.yaxis.set_minor_locator(FixedLocator([]))


def _missing_note(regimes: list[str], algos: list[str], df: pd.DataFrame) -> list[str]:
    present = set(map(tuple, df[["regime", "algo"]].drop_duplicates().to_numpy()))
    missing = [f"{algo_label(a)}/{r}" for r in regimes for a in algos if (r, a) not in present]
    return [f"no data: {', '.join(missing)}"] if missing else []


def eval_across_regimes(
    df: pd.DataFrame,
    algos: list[str] | None = None,
    references: pd.DataFrame | None = None,
    title: str = "Fixed-policy inference across regimes",
) -> FigureResult:
    """Figures 3 and 4: evaluation metrics per regime, panels (A) return, (B) final distance,
    (C) foods consumed, (D) overshoot ratio; one line per algorithm, mean over seeds x
    evaluation episodes with a standard-error band over the same pooled episodes.

    ``references``: optional rows (regime, policy, metric columns) of the simple policies,
    drawn as thin grey lines so the reader sees where no learning and full information lie.
    """
    ev = df[df["phase"] == "eval"]
    if algos is not None:
        ev = ev[ev["algo"].isin(algos)]
    if ev.empty:
        raise ValueError("no evaluation episodes to plot" + (f" for {', '.join(algos)}" if algos else ""))
    regimes = sort_regimes(ev["regime"])
    if references is not None:
        regimes = sort_regimes(set(regimes))
    xs = {r: (regime_index(r) if regime_index(r) is not None else i) for i, r in enumerate(regimes)}
    present_algos = sort_algos(ev["algo"])
    fig = Figure(figsize=(11, 7.6), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    rows = []
    for p, metric in enumerate(EVAL_PANELS):
        ax = axes.flat[p]
        for i, algo in enumerate(present_algos):
            cell = ev[ev["algo"] == algo]
            g = cell.groupby("regime")[metric]
            stats = pd.DataFrame({"mean": g.mean(), "count": g.count(), "std": g.std(ddof=1)})
            stats = stats.loc[sort_regimes(stats.index)]
            stats["sem"] = stats["std"] / np.sqrt(stats["count"])
            x = np.array([xs[r] for r in stats.index])
            ax.plot(x, stats["mean"], marker="o", ms=4, color=algo_color(algo, i), label=algo_label(algo))
            ax.fill_between(x, stats["mean"] - stats["sem"], stats["mean"] + stats["sem"], color=algo_color(algo, i), alpha=0.2, lw=0)
            rows.append(
                pd.DataFrame({"panel": metric, "algo": algo, "regime": stats.index, "x": x, "mean": stats["mean"].to_numpy(), "sem": stats["sem"].to_numpy(), "n": stats["count"].to_numpy()})
            )
        if references is not None and not references.empty:
            ref = references[references["regime"].isin(regimes)]
            for policy, style in POLICY_STYLES.items():
                r = ref[ref["policy"] == policy]
                if r.empty:
                    continue
                r = r.set_index("regime").loc[sort_regimes(r["regime"])]
                ax.plot([xs[k] for k in r.index], r[metric], lw=0.8, ms=4, alpha=0.9, label=f"{policy} (reference)", **style)
        ax.set_title(f"({'ABCD'[p]}) {METRIC_LABELS[metric]}", fontsize=10, loc="left")
        ax.grid(alpha=0.3)
        if metric == "return" and references is not None:
            _symlog_return_axis(ax)
        if p >= 2:
            ax.set_xlabel("regime (run)")
            ax.set_xticks(sorted(xs.values()), [str(k) for k in sorted(xs.values())])
    handles, labels = axes.flat[0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=min(5, len(labels)), fontsize=9, frameon=False)
    notes = _missing_note(regimes, present_algos, ev)
    if algos is not None:
        absent = [algo_label(a) for a in algos if a not in present_algos]
        if absent:
            notes.append(f"no evaluation data for {', '.join(absent)}")
    n = ev.groupby(["regime", "algo"]).size()
    fig.suptitle(f"{title}\nmean over seeds x evaluation episodes ({n.min()}-{n.max()} per point); band = standard error", fontsize=10)
    if notes:
        fig.text(0.99, 0.005, "; ".join(notes), ha="right", va="bottom", fontsize=7, color="0.3")
    return FigureResult(fig, pd.concat(rows, ignore_index=True), notes)
