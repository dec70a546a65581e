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

from nutribench.report.figure_parts import (  # noqa: F401 (re-exported: the figures' shared parts)
    BEST_TEXT,
    LEGEND_COLS,
    MARKS,
    FigureResult,
    agent_labels,
    budget_seeds_line,
    budget_seeds_text,
    count_span,
    default_window,
    draw_notes,
    legend_rows,
    regime_index,
    seed_list,
    set_title,
    sort_regimes,
    training_legend,
    wrap_text,
)
from nutribench.report.palette import Palette, palette
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos
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
#: The references above the planner on panel (A)'s gap scale (:mod:`nutribench.report.headroom`).
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
    ncols = min(4, len(panels))
    nrows = int(np.ceil(len(panels) / ncols))
    fig = Figure(figsize=(max(7.5, 4.2 * ncols), 3.2 * nrows + 0.9), layout="constrained")
    axes = fig.subplots(nrows, ncols, squeeze=False, sharex=not split)
    rows = []
    for k, (regime, budget) in enumerate(panels):
        ax = axes.flat[k]
        sub = train[train["regime"] == regime]
        best = -np.inf
        for algo in algos:
            cell = sub[sub["algo"] == algo]
            if cell.empty or (budget is not None and int(cell["budget"].max()) != budget):
                continue
            wide = cell.pivot_table(index="seed", columns="episode", values=metric, aggfunc="mean").sort_index(axis=1)
            smoothed = wide.T.rolling(window, min_periods=1).mean().T.to_numpy()
            mean, se = _seed_band(smoothed)
            x = wide.columns.to_numpy()
            step = max(1, len(x) // MARKS)
            ax.plot(
                x,
                mean,
                color=colors.color(algo),
                lw=1.4,
                label=legend[algo],
                marker=colors.marker(algo),
                ms=5,
                markevery=(algos.index(algo) * step // len(algos), step),
            )
            if not np.all(np.isnan(se)):
                ax.fill_between(x, mean - se, mean + se, color=colors.color(algo), alpha=0.2, lw=0)
            best = max(best, float(np.nanmax(mean)))
            rows.append(
                pd.DataFrame(
                    {"regime": regime, "algo": algo, "episode": x, "mean": mean, "sem": se, "n_seeds": wide.shape[0]}
                )
            )
        if best_line and np.isfinite(best):
            ax.axhline(best, color="k", ls="--", lw=0.9, label="best (smoothed)" if window > 1 else "best")
        ax.set_title(f"{regime}" + (f", budget {budget} days" if budget is not None else ""), fontsize=10)
        ax.grid(alpha=0.3)
        if k % ncols == 0:
            ax.set_ylabel(METRIC_LABELS.get(metric, metric))
        if split or k >= len(panels) - ncols:  # no panel below (or axes of their own): an x axis
            ax.set_xlabel("training episode")
            ax.tick_params(labelbottom=True)
    for ax in list(axes.flat)[len(panels) :]:
        ax.set_visible(False)
    training_legend(fig, list(axes.flat)[: len(panels)], [legend[a] for a in algos])
    notes = _missing_note(regimes, algos, train)
    n_seeds = train.groupby(["regime", "algo"])["seed"].nunique()
    smoothing = f"a {window}-episode moving average" if window > 1 else "the per-episode values (no smoothing)"
    band = "band = standard error across seeds" if n_seeds.max() > 1 else "one seed: no band"
    caption = f"mean over seeds ({count_span(n_seeds)} per line) of {smoothing}; {band}\n{budget_seeds_line(train)}"
    set_title(fig, (title or f"Training {METRIC_LABELS.get(metric, metric)}") + f"\n{caption}")
    draw_notes(fig, notes)
    return FigureResult(fig, pd.concat(rows, ignore_index=True), notes)


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


def gap_axis(ax) -> None:
    """Panel (A) on the gap scale: linear, 0 = never eat, 100 % = the full-information planner,
    so equal distances are equal shares of what there is to gain."""
    from matplotlib.ticker import PercentFormatter

    ax.yaxis.set_major_formatter(PercentFormatter(xmax=1, decimals=0))
    for v in (0.0, 1.0):
        ax.axhline(v, color="0.5", ls=":", lw=0.9, zorder=0)
    ax.set_ylabel("0 = never eat, 100 % = planner (linear)", fontsize=8)


def seed_scores(ev: pd.DataFrame, day_references: pd.DataFrame) -> pd.DataFrame:
    """Per (regime, algo, seed): the share of the never -> planner gap the seed's mean return
    closes on its own evaluation days (the results table's "gap closed", per seed); NaN where a
    day has no yardstick. Columns: regime, algo, seed, score."""
    ref = day_references.set_index(["regime", "seed", "episode"])[["never", "planner"]]
    rows = []
    for (regime, algo, seed), days in ev.groupby(["regime", "algo", "seed"], sort=True):
        yard = ref.reindex(pd.MultiIndex.from_arrays([days["regime"], days["seed"], days["episode"]]))
        score = float("nan")
        if not yard.isna().any().any():
            never, planner = float(yard["never"].mean()), float(yard["planner"].mean())
            if planner != never:
                score = (float(days["return"].mean()) - never) / (planner - never)
        rows.append({"regime": regime, "algo": algo, "seed": seed, "score": score})
    return pd.DataFrame(rows, columns=["regime", "algo", "seed", "score"])


def _reference_scores(references: pd.DataFrame) -> pd.DataFrame:
    """The simple policies' reference lines on the gap scale: each policy's mean return as a
    share of the never -> planner gap on the same reference days (never = 0, planner = 1)."""
    wide = references.pivot_table(index="regime", columns="policy", values="return", aggfunc="mean")
    if not {"never", "planner"} <= set(wide.columns):
        return references.iloc[0:0]
    gap = (wide["planner"] - wide["never"]).replace(0.0, np.nan)
    out = references.copy()
    out["return"] = [(r - wide.loc[g, "never"]) / gap.loc[g] for g, r in zip(out["regime"], out["return"])]
    return out


def _draw_headroom(ax, ev: pd.DataFrame, day_references: pd.DataFrame, xs: Mapping[str, float]) -> list[str]:
    """Lookahead's and clairvoyant's shares of the gap per regime on panel (A) (the mean over
    the seeds' days ``ev`` holds, :func:`nutribench.report.headroom.regime_shares`), as grey
    reference lines; the policies drawn."""
    from nutribench.report.headroom import regime_shares

    return _reference_lines(ax, regime_shares(ev, day_references), "share", STRONG_STYLES, xs)


def _reference_lines(ax, ref: pd.DataFrame, column: str, styles: Mapping, xs: Mapping[str, float]) -> list[str]:
    """Each policy of ``styles`` that ``ref`` holds (columns policy, regime, ``column``) as a
    reference line across its regimes, broken where regimes are missing; the policies drawn."""
    drawn = []
    for policy, style in styles.items():
        r = ref[ref["policy"] == policy]
        if r.empty:
            continue
        r = r.set_index("regime").loc[sort_regimes(r["regime"])]
        ax.plot(
            *_with_breaks([xs[k] for k in r.index], r[column].to_numpy(dtype=float)),
            lw=0.8,
            ms=4,
            alpha=0.9,
            label=f"{policy} (reference)",
            **style,
        )
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
    left = np.r_[False, has[:-1]]
    right = np.r_[has[1:], False]
    alone = has & ~left & ~right
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
    ev = df[df["phase"] == "eval"]
    if algos is not None:
        ev = ev[ev["algo"].isin(algos)]
    if ev.empty:
        raise ValueError("no evaluation episodes to plot" + (f" for {', '.join(algos)}" if algos else ""))
    regimes = sort_regimes(ev["regime"])
    xs = {r: (regime_index(r) if regime_index(r) is not None else i) for i, r in enumerate(regimes)}
    present_algos = sort_algos(ev["algo"])
    colors = colors or palette(present_algos)
    legend = agent_labels(ev, dict(labels or {}))
    notes: list[str] = []
    scores = None
    headroom: list[str] = []
    if day_references is not None:
        scores = seed_scores(ev, day_references)
        unscored = sort_regimes(scores.loc[~np.isfinite(scores["score"].to_numpy(dtype=float)), "regime"].unique())
        if unscored:
            notes.append(
                f"panel (A) shows returns, not the share of the gap: no never/planner yardsticks for {', '.join(unscored)} "
                "(the regime file is not the version the jobs ran)"
            )
            scores = None
    fig = Figure(figsize=(11, 7.6), layout="constrained")
    axes = fig.subplots(2, 2, sharex=True)
    # each algorithm drawn slightly beside the regime's x, so that lines which coincide
    # (several agents that learned the same policy) stay visible; ``data["x"]`` is the regime
    dodge = {a: DODGE * (i - (len(present_algos) - 1) / 2) for i, a in enumerate(present_algos)}
    rows = []
    for p, metric in enumerate(EVAL_PANELS):
        ax = axes.flat[p]
        gap_panel = metric == "return" and scores is not None
        for algo in present_algos:
            cell, color = ev[ev["algo"] == algo], colors.color(algo)
            g = cell.groupby("regime")[metric]
            stats = pd.DataFrame({"count": g.count(), "std": g.std(ddof=1)})
            stats = stats.loc[sort_regimes(stats.index)]
            stats["sem"] = stats["std"] / np.sqrt(stats["count"])
            if gap_panel:
                per_seed = scores[scores["algo"] == algo].groupby("regime")["score"]
                stats["sem"] = np.nan  # the pooled standard error is a return's, not a share's
            else:
                per_seed = cell.groupby(["regime", "seed"])[metric].mean().groupby("regime")
            ci = {r: mean_ci(v.to_numpy(dtype=float)) for r, v in per_seed}
            stats["mean"] = [ci[r][0] for r in stats.index]
            stats["lo"] = [ci[r][1] for r in stats.index]
            stats["hi"] = [ci[r][2] for r in stats.index]
            stats["seeds"] = [int(cell[cell["regime"] == r]["seed"].nunique()) for r in stats.index]
            x = np.array([xs[r] for r in stats.index])
            xd = [xs[r] + dodge[algo] for r in regimes]
            _draw_gapped(ax, stats, regimes, xd, color, legend[algo], colors.marker(algo))
            rows.append(
                pd.DataFrame(
                    {
                        "panel": "gap_closed" if gap_panel else metric,
                        "algo": algo,
                        "regime": stats.index,
                        "x": x,
                        "mean": stats["mean"].to_numpy(),
                        "lo": stats["lo"].to_numpy(),
                        "hi": stats["hi"].to_numpy(),
                        "sem": stats["sem"].to_numpy(),
                        "n": stats["count"].to_numpy(),
                        "seeds": stats["seeds"].to_numpy(),
                    }
                )
            )
        if references is not None and not references.empty:
            ref = references[references["regime"].isin(regimes)]
            if gap_panel:
                ref = _reference_scores(ref)
            _reference_lines(ax, ref, metric, POLICY_STYLES, xs)
        if gap_panel:
            headroom = _draw_headroom(ax, ev, day_references, xs)
        panel_title = GAP_LABEL if gap_panel else METRIC_LABELS[metric]
        ax.set_title(f"({'ABCD'[p]}) {panel_title}", fontsize=10, loc="left")
        ax.grid(alpha=0.3)
        if gap_panel:
            gap_axis(ax)
        elif metric == "return":
            ax.set_ylabel("return (linear)", fontsize=8)
        # half a regime beyond the outermost: a figure of one regime has its points in the
        # middle of the panel (autoscaling put two dodged points at its two edges)
        ax.set_xlim(min(xs.values()) - 0.5, max(xs.values()) + 0.5)
        if p >= 2:
            ax.set_xlabel("regime (run)")
            ax.set_xticks(sorted(xs.values()), [str(k) for k in sorted(xs.values())])
    handles, labels = axes.flat[0].get_legend_handles_labels()
    is_ref = [lab.endswith("(reference)") for lab in labels]
    legend_rows(
        fig,
        [
            ([h for h, r in zip(handles, is_ref) if not r], [lab for lab, r in zip(labels, is_ref) if not r]),
            ([h for h, r in zip(handles, is_ref) if r], [lab for lab, r in zip(labels, is_ref) if r]),
        ],
    )
    notes = _missing_note(regimes, present_algos, ev) + notes
    if algos is not None:
        absent = [algo_label(a) for a in algos if a not in present_algos]
        if absent:
            notes.append(f"no evaluation data for {', '.join(absent)}")
    n_seeds = ev.groupby(["regime", "algo"])["seed"].nunique()
    n_days = ev.groupby(["regime", "algo", "seed"]).size()
    band = (
        f"band (or error bar) = 95 % interval over seeds of the seed means ({caption('mean')})"
        if n_seeds.max() > 1
        else "one seed: no band"
    )
    panel_a = (
        "(A) each seed's share of the never -> planner gap closed on its own evaluation days; returns in the results table"
        if scores is not None
        else "(A) return"
    )
    if scores is not None and headroom:
        panel_a += (
            f";\n(A)'s {' and '.join(headroom)}: the references above the planner on the same days (mean over seeds)"
        )
    set_title(
        fig,
        f"{title}\nmean over seeds ({count_span(n_seeds)} per point) of each seed's mean over its evaluation days ({count_span(n_days)});\n"
        f"{band}; {panel_a};\nalgorithms are drawn slightly apart along x so that equal values stay visible\n{budget_seeds_line(ev)}",
    )
    draw_notes(fig, notes)
    return FigureResult(fig, pd.concat(rows, ignore_index=True), notes)
