"""Figure builders: pure functions from a DataFrame of episode metrics to a matplotlib Figure.

Input columns (those of the ``episode_metrics`` view): ``regime``, ``algo``, ``seed``,
``phase`` ("train" / "eval"), ``episode`` and the metric columns (``return``, ``foods``,
``final_distance``, ``overshoot_ratio``) and, where known, ``budget`` (training days of the
job). The order, colour and label of each config: :mod:`nutribench.report.palette`. Every
figure states the training budget and the seeds of what it drew. Each builder returns a
:class:`FigureResult` holding the Figure and the exact numbers it drew, so tests (and curious readers) can
check them without parsing pixels.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from nutribench.baselines import gap_closed
from nutribench.report.figure_parts import (
    MARKS,
    FigureResult,
    agent_labels,
    budget_seeds_line,
    count_span,
    default_window,
    legend_rows,
    regime_index,
    set_title,
    sort_regimes,
    training_legend,
)
from nutribench.report.palette import Palette, palette
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos
from nutribench.report.references import regime_shares
from nutribench.report.scores import run_scores
from nutribench.stats import caption, mean_ci

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
#: The references above the planner on panel (A)'s gap scale (:mod:`nutribench.report.references`).
STRONG_STYLES = {
    "lookahead": dict(color="0.3", ls="--", marker="^"),
    "clairvoyant": dict(color="0.3", ls="-", marker="v"),
}
EVAL_PANELS = ["return", "final_distance", "foods", "overshoot_ratio"]


def _seed_band(curves: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean and standard error across seeds (rows); SE is NaN with one seed."""
    mean = np.nanmean(curves, axis=0)
    if curves.shape[0] < 2:
        return mean, np.full_like(mean, np.nan)
    n = np.sum(~np.isnan(curves), axis=0)
    se = np.nanstd(curves, axis=0, ddof=1) / np.sqrt(np.maximum(n, 1))
    return mean, se


def panel_grid(n: int, extra: float, sharex: bool) -> tuple[Figure, np.ndarray, int]:
    """A figure of ``n`` panels of one size, at most four a row (``extra``: inches for the title
    and the legend): the figure, its ``n`` axes (the others hidden) and the number of columns."""
    ncols = min(4, n)
    nrows = int(np.ceil(n / ncols))
    fig = Figure(figsize=(max(7.5, 4.2 * ncols), 3.2 * nrows + extra), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=sharex).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes[:n], ncols


def dress_panel(ax, k: int, n: int, ncols: int, title: str, label: str, own_axis: bool = False) -> None:
    """Panel ``k`` of ``n``: its title and grid, and an x label and tick labels where no panel
    is below it (or where each panel has its x axis of its own)."""
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    if own_axis or k >= n - ncols:
        ax.set_xlabel(label)
        ax.tick_params(labelbottom=True)


def training_curves(
    df: pd.DataFrame,
    metric: str = "return",
    window: int | None = None,
    best_line: bool = True,
    title: str | None = None,
    colors: Palette | None = None,
) -> FigureResult:
    """Figures 1 and 2: a training metric per episode, one panel per regime present, one line
    per algorithm (mean over seeds of the per-seed moving average, shaded standard error
    across seeds, the agent's marker every few episodes), and a dashed line at the best value
    of the panel: the highest point any agent's (smoothed) mean curve reaches there, so the
    reader sees how far each line ends below it; its legend entry says so.

    ``colors``: the report's palette (default: one over the configs drawn)."""
    train = df[df["phase"] == "train"]
    if train.empty:
        raise ValueError("no training episodes to plot")
    regimes = sort_regimes(train["regime"])
    algos = sort_algos(train["algo"])
    colors = colors or palette(algos)
    legend = agent_labels(train)
    if window is None:
        window = default_window(int(train["episode"].max()) + 1)
    panels = budget_panels(train, regimes)
    split = any(b is not None for _, b in panels)
    fig, axes, ncols = panel_grid(len(panels), 0.9, sharex=not split)
    rows = []
    for k, ((regime, budget), ax) in enumerate(zip(panels, axes)):
        best = -np.inf
        for algo in algos:
            cell = train[(train["regime"] == regime) & (train["algo"] == algo)]
            if cell.empty or (budget is not None and int(cell["budget"].max()) != budget):
                continue
            line = _training_line(ax, cell, metric, window, colors, algo, legend[algo], algos)
            best = max(best, float(np.nanmax(line["mean"])))
            rows.append(line.assign(regime=regime)[["regime", "algo", "episode", "mean", "sem", "n_seeds"]])
        if best_line and np.isfinite(best):
            ax.axhline(best, color="k", ls="--", lw=0.9, label="best (smoothed)" if window > 1 else "best")
        heading = f"{regime}" + (f", budget {budget} days" if budget is not None else "")
        dress_panel(ax, k, len(panels), ncols, heading, "training episode", own_axis=split)
        if k % ncols == 0:
            ax.set_ylabel(METRIC_LABELS.get(metric, metric))
    training_legend(fig, list(axes), [legend[a] for a in algos])
    notes = _missing_note(regimes, algos, train)
    n_seeds = train.groupby(["regime", "algo"])["seed"].nunique()
    smoothing = f"a {window}-episode moving average" if window > 1 else "the per-episode values (no smoothing)"
    band = "band = standard error across seeds" if n_seeds.max() > 1 else "one seed: no band"
    caption = f"mean over seeds ({count_span(n_seeds)} per line) of {smoothing}; {band}\n{budget_seeds_line(train)}"
    set_title(fig, (title or f"Training {METRIC_LABELS.get(metric, metric)}") + f"\n{caption}", notes)
    return FigureResult(fig, pd.concat(rows, ignore_index=True), notes)


def _training_line(ax, cell: pd.DataFrame, metric: str, window: int, colors: Palette, algo: str, label: str, algos):
    """One agent's smoothed mean curve over its seeds, its standard-error band and markers;
    what was drawn (episode, mean, sem, n_seeds)."""
    wide = cell.pivot_table(index="seed", columns="episode", values=metric, aggfunc="mean").sort_index(axis=1)
    mean, se = _seed_band(wide.T.rolling(window, min_periods=1).mean().T.to_numpy())
    x = wide.columns.to_numpy()
    step = max(1, len(x) // MARKS)
    color = colors.color(algo)
    markevery = (algos.index(algo) * step // len(algos), step)
    ax.plot(x, mean, color=color, lw=1.4, label=label, marker=colors.marker(algo), ms=5, markevery=markevery)
    if not np.all(np.isnan(se)):
        ax.fill_between(x, mean - se, mean + se, color=color, alpha=0.2, lw=0)
    return pd.DataFrame({"algo": algo, "episode": x, "mean": mean, "sem": se, "n_seeds": wide.shape[0]})


def budget_panels(train: pd.DataFrame, regimes: list[str]) -> list[tuple[str, int | None]]:
    """The panels of Figures 1/2: one per regime, or, when the configs drawn were trained for
    different budgets, one per (budget, regime) with its own x axis (a 50-day run is not
    squeezed into the first 1 % of a 5000-day axis); budget None when there is one."""
    if "budget" not in train or train["budget"].isna().all():
        return [(r, None) for r in regimes]
    cells = train.groupby(["regime", "algo"])["budget"].max()
    budgets = sorted({int(b) for b in cells})
    if len(budgets) == 1:
        return [(r, None) for r in regimes]
    return [(r, b) for b in budgets for r in regimes if any(int(v) == b for v in cells.loc[r])]


#: Label of Figures 3/4 panel (A) when it shows the share of the never -> planner gap.
GAP_LABEL = "share of the never -> planner gap closed"


def gap_scale(ax, vertical: bool = True) -> None:
    """The gap scale along x (``vertical``: its lines stand upright) or y: shares as whole
    percents, and dotted grey lines at never (0) and the planner (1)."""
    from matplotlib.ticker import PercentFormatter

    (ax.xaxis if vertical else ax.yaxis).set_major_formatter(PercentFormatter(xmax=1, decimals=0))
    for v in (0.0, 1.0):
        (ax.axvline if vertical else ax.axhline)(v, color="0.5", ls=":", lw=0.9, zorder=0)


def gap_axis(ax) -> None:
    """Panel (A) on the gap scale: linear, 0 = never eat, 100 % = the full-information planner,
    so equal distances are equal shares of what there is to gain."""
    gap_scale(ax, vertical=False)
    ax.set_ylabel("0 = never eat, 100 % = planner (linear)", fontsize=8)


def _reference_scores(references: pd.DataFrame) -> pd.DataFrame:
    """The simple policies' reference lines on the gap scale: each policy's mean return as a
    share of the never -> planner gap on the same reference days (never = 0, planner = 1)."""
    wide = references.pivot_table(index="regime", columns="policy", values="return", aggfunc="mean")
    if not {"never", "planner"} <= set(wide.columns):
        return references.iloc[0:0]
    out = references.copy()
    out["return"] = [
        gap_closed(r, wide.loc[g, "never"], wide.loc[g, "planner"]) for g, r in zip(out["regime"], out["return"])
    ]
    return out


def _reference_lines(ax, ref: pd.DataFrame, column: str, styles: Mapping, xs: Mapping[str, float]) -> list[str]:
    """Each policy of ``styles`` that ``ref`` holds (columns policy, regime, ``column``) as a
    reference line across its regimes, broken where regimes are missing; the policies drawn."""
    drawn = []
    for policy, style in styles.items():
        r = ref[ref["policy"] == policy]
        if r.empty:
            continue
        r = r.set_index("regime").loc[sort_regimes(r["regime"])]
        xy = _with_breaks([xs[k] for k in r.index], r[column].to_numpy(dtype=float))
        ax.plot(*xy, lw=0.8, ms=4, alpha=0.9, label=f"{policy} (reference)", **style)
        drawn.append(policy)
    return drawn


def _missing_note(regimes: list[str], algos: list[str], df: pd.DataFrame) -> list[str]:
    present = set(map(tuple, df[["regime", "algo"]].drop_duplicates().to_numpy()))
    missing = [f"{algo_label(a)}/{r}" for r in regimes for a in algos if (r, a) not in present]
    return [f"no data: {', '.join(missing)}"] if missing else []


def _with_breaks(x: np.ndarray, *ys: np.ndarray) -> tuple[np.ndarray, ...]:
    """``x`` and ``ys`` with a NaN point inserted wherever two neighbouring x positions are
    more than one regime apart (run0 next to run3: run1 and run2 were not run), so that no
    line or band is drawn across regimes that have no data."""
    x = np.asarray(x, dtype=float)
    cuts = np.flatnonzero(np.diff(np.round(x)) > 1) + 1
    return tuple(np.insert(np.asarray(v, dtype=float), cuts, np.nan) for v in (x, *ys))


def _draw_gapped(
    ax, stats: pd.DataFrame, regimes: list[str], xd: list[float], color: str, label: str, marker: str = "o"
) -> None:
    """One agent's line and band over the figure's ``regimes`` (x positions ``xd``), broken
    where it has no data (no line drawn across a regime it was not evaluated on, nor across
    a regime number no agent ran); a point with no neighbour has no band width, so its
    interval is drawn as an error bar."""
    full = stats.reindex(regimes)
    x, mean, lo, hi = _with_breaks(xd, *(full[c].to_numpy(dtype=float) for c in ("mean", "lo", "hi")))
    ax.plot(x, mean, marker=marker, ms=5, color=color, label=label)
    ax.fill_between(x, lo, hi, color=color, alpha=0.2, lw=0)
    has = np.isfinite(mean)
    alone = has & ~np.r_[False, has[:-1]] & ~np.r_[has[1:], False]  # no neighbour on the left or right
    if alone.any():
        err = np.array([mean[alone] - lo[alone], hi[alone] - mean[alone]])
        ax.errorbar(x[alone], mean[alone], yerr=err, fmt="none", ecolor=color, capsize=4, lw=1.2)


#: Horizontal offset between neighbouring algorithms in Figures 3 and 4 (regime units).
DODGE = 0.06


def eval_across_regimes(
    df: pd.DataFrame,
    algos: list[str] | None = None,
    references: pd.DataFrame | None = None,
    title: str = "Fixed-policy inference across regimes",
    colors: Palette | None = None,
    day_references: pd.DataFrame | None = None,
    bootstrap: int = 2000,
    labels: Mapping[str, str] | None = None,
) -> FigureResult:
    """Figures 3 and 4: evaluation metrics per regime, panels (A) return, (B) final distance,
    (C) foods consumed, (D) overshoot ratio; one line per algorithm at the mean of the seeds'
    means (each seed's mean over its evaluation days), with a band of the 95 % interval over
    seeds (:func:`nutribench.stats.mean_ci`, the method the coverage simulation chose; no band
    with one seed). ``bootstrap``: kept for callers; the chosen interval needs no resamples.

    ``day_references`` (columns regime, seed, episode, never, planner: the yardsticks on each
    evaluation day, :func:`nutribench.report.references.eval_day_references`): panel (A) then
    shows each seed's share of the never -> planner gap closed on its own days, on a linear
    axis (0 = never, 100 % = planner), so distances between agents read truly; where a regime
    drawn has no yardsticks (its regime file is not the version the jobs ran) panel (A) falls
    back to returns on a linear axis, with a note. ``res.data`` keeps, per point, the mean and
    the pooled standard error over seeds x days (``sem``, the paper's band) beside the
    interval drawn (``lo``, ``hi``) and the seed count (``seeds``); panel "return" rows hold
    returns, panel "gap_closed" rows shares.

    ``references``: optional rows (regime, policy, metric columns) of the simple policies,
    drawn as thin grey lines so the reader sees where no learning and full information lie.
    ``colors``: the report's palette (default: one over the configs drawn). ``labels``: legend
    labels of some configs instead of :func:`~nutribench.report.palette.label`.
    """
    ev = _eval_days(df, algos)
    regimes = sort_regimes(ev["regime"])
    xs = {r: (regime_index(r) if regime_index(r) is not None else i) for i, r in enumerate(regimes)}
    present = sort_algos(ev["algo"])
    colors = colors or palette(present)
    legend = agent_labels(ev, dict(labels or {}))
    scores, notes = _gap_scores(ev, day_references)
    fig = Figure(figsize=(11, 7.6), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    rows, headroom = [], []
    for p, metric in enumerate(EVAL_PANELS):
        ax = axes.flat[p]
        gap_panel = metric == "return" and scores is not None
        rows += _agent_lines(ax, ev, metric, scores if gap_panel else None, regimes, xs, colors, legend)
        if references is not None and not references.empty:
            ref = references[references["regime"].isin(regimes)]
            _reference_lines(ax, _reference_scores(ref) if gap_panel else ref, metric, POLICY_STYLES, xs)
        if gap_panel:  # lookahead's and clairvoyant's shares per regime (mean over the seeds' days ev holds)
            headroom = _reference_lines(ax, regime_shares(ev, day_references), "share", STRONG_STYLES, xs)
        _eval_axes(ax, p, metric, gap_panel, xs)
    _reference_legend(fig, axes.flat[0])
    notes = _missing_note(regimes, present, ev) + notes
    absent = [algo_label(a) for a in algos or () if a not in present]
    if absent:
        notes.append(f"no evaluation data for {', '.join(absent)}")
    set_title(fig, f"{title}\n{_eval_caption(ev, scores is not None, headroom)}", notes)
    return FigureResult(fig, pd.concat(rows, ignore_index=True), notes)


def _eval_days(df: pd.DataFrame, algos: list[str] | None) -> pd.DataFrame:
    """The evaluation days of ``algos`` (default all); ValueError when there are none."""
    ev = df[df["phase"] == "eval"]
    if algos is not None:
        ev = ev[ev["algo"].isin(algos)]
    if ev.empty:
        raise ValueError("no evaluation episodes to plot" + (f" for {', '.join(algos)}" if algos else ""))
    return ev


def _agent_lines(ax, ev, metric: str, scores, regimes: list[str], xs, colors: Palette, legend) -> list[pd.DataFrame]:
    """One panel's agents, each a line with its band (:func:`_draw_gapped`) over the regimes at
    the mean of its seeds' means (``scores``: the seeds' shares of the gap instead); each drawn
    slightly beside the regime's x, so that lines which coincide (several agents that learned
    the same policy) stay visible (``data["x"]`` is the regime). What was drawn."""
    present = sort_algos(ev["algo"])
    dodge = {a: DODGE * (i - (len(present) - 1) / 2) for i, a in enumerate(present)}
    rows = []
    for algo in present:
        cell = ev[ev["algo"] == algo]
        stats = _regime_stats(cell, metric, scores[scores["algo"] == algo] if scores is not None else None)
        xd = [xs[r] + dodge[algo] for r in regimes]
        _draw_gapped(ax, stats, regimes, xd, colors.color(algo), legend[algo], colors.marker(algo))
        x = np.array([xs[r] for r in stats.index])
        frame = stats.reset_index(names="regime").assign(x=x, n=stats["count"].to_numpy())
        rows.append(frame.assign(panel="gap_closed" if scores is not None else metric, algo=algo)[_EVAL_COLUMNS])
    return rows


_EVAL_COLUMNS = ["panel", "algo", "regime", "x", "mean", "lo", "hi", "sem", "n", "seeds"]


def _gap_scores(ev: pd.DataFrame, day_references: pd.DataFrame | None) -> tuple[pd.DataFrame | None, list[str]]:
    """Each seed's share of the gap (its run score, :func:`~nutribench.report.scores.run_scores`) for panel (A), or None (and a note
    where a regime drawn has no yardsticks: panel (A) shows returns)."""
    if day_references is None:
        return None, []
    scores = run_scores(ev, day_references)
    unscored = sort_regimes(scores.loc[~np.isfinite(scores["score"].to_numpy(dtype=float)), "regime"].unique())
    if not unscored:
        return scores, []
    return None, [
        f"panel (A) shows returns, not the share of the gap: no never/planner yardsticks for {', '.join(unscored)} "
        "(the regime file is not the version the jobs ran)"
    ]


def _regime_stats(cell: pd.DataFrame, metric: str, scores: pd.DataFrame | None) -> pd.DataFrame:
    """Per regime of one agent's days: the pooled count and standard error over seeds x days
    (``sem``: NaN on the gap scale, where it is a return's), the mean of the seeds' means (of
    ``scores``, the seeds' shares, when given) with its interval over seeds, the seed count."""
    g = cell.groupby("regime")[metric]
    stats = pd.DataFrame({"count": g.count(), "std": g.std(ddof=1)})
    stats = stats.loc[sort_regimes(stats.index)]
    stats["sem"] = stats["std"] / np.sqrt(stats["count"])
    if scores is not None:
        per_seed = scores.groupby("regime")["score"]
        stats["sem"] = np.nan  # the pooled standard error is a return's, not a share's
    else:
        per_seed = cell.groupby(["regime", "seed"])[metric].mean().groupby("regime")
    ci = {r: mean_ci(v.to_numpy(dtype=float)) for r, v in per_seed}
    stats[["mean", "lo", "hi"]] = [ci[r] for r in stats.index]
    stats["seeds"] = [int(cell[cell["regime"] == r]["seed"].nunique()) for r in stats.index]
    return stats


def _eval_axes(ax, p: int, metric: str, gap_panel: bool, xs: Mapping[str, float]) -> None:
    """Panel ``p``'s title, grid, y label and x range (half a regime beyond the outermost: a
    figure of one regime has its points in the middle, not two dodged points at its edges)."""
    ax.set_title(f"({'ABCD'[p]}) {GAP_LABEL if gap_panel else METRIC_LABELS[metric]}", fontsize=10, loc="left")
    ax.grid(alpha=0.3)
    if gap_panel:
        gap_axis(ax)
    elif metric == "return":
        ax.set_ylabel("return (linear)", fontsize=8)
    ax.set_xlim(min(xs.values()) - 0.5, max(xs.values()) + 0.5)
    if p >= 2:
        ax.set_xlabel("regime (run)")
        ax.set_xticks(sorted(xs.values()), [str(k) for k in sorted(xs.values())])


def _reference_legend(fig: Figure, ax) -> None:
    """The legend under the panels: the agents in a row, the reference lines in the next."""
    entries = list(zip(*ax.get_legend_handles_labels()))
    groups = [[(h, lab) for h, lab in entries if lab.endswith("(reference)") == ref] for ref in (False, True)]
    legend_rows(fig, [([h for h, _ in g], [lab for _, lab in g]) for g in groups])


def _eval_caption(ev: pd.DataFrame, gap: bool, headroom: list[str]) -> str:
    """Figures 3/4's caption: what a point and a band are, what panel (A) shows, the budgets and seeds."""
    n_seeds = ev.groupby(["regime", "algo"])["seed"].nunique()
    n_days = ev.groupby(["regime", "algo", "seed"]).size()
    band = (
        f"band (or error bar) = 95 % interval over seeds of the seed means ({caption('mean')})"
        if n_seeds.max() > 1
        else "one seed: no band"
    )
    panel_a = (
        "(A) each seed's share of the never -> planner gap closed on its own evaluation days; returns in the results table"
        if gap
        else "(A) return"
    )
    if gap and headroom:
        panel_a += (
            f";\n(A)'s {' and '.join(headroom)}: the references above the planner on the same days (mean over seeds)"
        )
    return (
        f"mean over seeds ({count_span(n_seeds)} per point) of each seed's mean over its evaluation days ({count_span(n_days)});\n"
        f"{band}; {panel_a};\nalgorithms are drawn slightly apart along x so that equal values stay visible\n{budget_seeds_line(ev)}"
    )
