"""The aggregate figure (Figure 5, ``fig5_aggregate``) and table (``table_aggregate``) of an
:class:`~nutribench.report.aggregate.AggregateResult`: what the statistics of
:mod:`nutribench.report.aggregate` computed, drawn and tabulated (result in, Figure / table out)."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from nutribench.report.aggregate import (
    AGGREGATE_LABELS,
    AGGREGATES,
    GROUPS,
    AggregateResult,
    group_title,
    regime_span,
)
from nutribench.report.figure_parts import (
    agent_labels,
    budget_caption,
    budget_cell,
    budget_seeds_line,
    count_span,
    legend_entries,
)
from nutribench.report.figures import FigureResult, gap_scale, legend_rows, set_title
from nutribench.report.palette import Palette, palette
from nutribench.report.palette import label as algo_label
from nutribench.report.tables import TableResult, interval_cell
from nutribench.stats import aggregate_caption
from nutribench.stats import caption as interval_caption

# --------------------------------------------------------------------------- figure
_GROUP_STYLE = {"all": dict(alpha=0.85, hatch=None), "delayed": dict(alpha=0.35, hatch="////")}
#: The point estimate's tick per group: solid above the agent's row, dotted below, so that
#: with one seed (no bars, ticks alone) the two still read apart; the legend names each.
_TICK_STYLE = {"all": dict(color="k", lw=1.8, ls="-"), "delayed": dict(color="k", lw=1.8, ls=":")}
_PLACE = {0.18: "upper", -0.18: "lower", 0.0: ""}


#: How the references above the planner are drawn on the aggregate panels.
_HEADROOM_STYLE = {"lookahead": dict(ls="--"), "clairvoyant": dict(ls="-")}


def _headroom_lines(ax, headroom: pd.DataFrame | None, agg: str) -> None:
    """Lookahead's and clairvoyant's aggregate ``agg`` over all regimes, as vertical grey lines."""
    if headroom is None:
        return
    for r in headroom[(headroom["group"] == "all") & (headroom["aggregate"] == agg)].itertuples(index=False):
        ax.axvline(
            r.point, color="0.35", lw=1.0, zorder=0, label=f"{r.policy} (reference)", **_HEADROOM_STYLE[r.policy]
        )


def aggregate_figure(
    res: AggregateResult,
    colors: Palette | None = None,
    title: str = "Aggregate scores over regimes and seeds",
    ev: pd.DataFrame | None = None,
    headroom: pd.DataFrame | None = None,
) -> FigureResult:
    """The aggregate figure: (top) IQM, median, mean and optimality gap per agent with 95 %
    intervals, both groups of regimes (all: upper row, solid bar and tick; delayed: lower row,
    hatched bar, dotted tick; the legend says which is which); (bottom) the performance
    profile of each group and the probability-of-improvement matrix of each group.

    ``ev``: the evaluation episodes the scores came from, for the budget and seeds line.
    ``headroom``: the references above the planner
    (:func:`nutribench.report.references.aggregate_points`), drawn on the IQM, median and mean
    panels as grey lines at their aggregate over all regimes."""
    colors = colors or palette(res.algos)
    names = agent_labels(ev) if ev is not None and not ev.empty else {}
    names = {a: names.get(a) or algo_label(a) for a in res.algos}
    groups = [g for g in GROUPS if res.regimes.get(g) or res.partial.get(g)]
    fig = Figure(figsize=(16, 9.6), layout="constrained")
    grid = fig.add_gridspec(2, 4, height_ratios=[1, 1.15])
    offset = {"all": 0.18, "delayed": -0.18} if len(groups) > 1 else {g: 0.0 for g in groups}
    drawn = _interval_panels(fig, grid, res, colors, names, groups, offset, headroom)
    profile_axes = [
        _profile_panel(fig.add_subplot(grid[1, j]), res, group, colors, names, j) for j, group in enumerate(GROUPS)
    ]
    for j, group in enumerate(GROUPS):
        _improvement_panel(fig, fig.add_subplot(grid[1, 2 + j]), res, group, colorbar=j == 1)
    _aggregate_legend(fig, res, names, profile_axes, groups, offset)
    notes = [*res.notes, *_width_notes(res)]
    set_title(fig, f"{title}\n{_aggregate_caption(res, ev, headroom)}", notes)
    return FigureResult(fig, pd.DataFrame(drawn, columns=["panel", "group", "algo", "y", "point", "lo", "hi"]), notes)


def _interval_panels(fig, grid, res: AggregateResult, colors: Palette, names, groups, offset, headroom) -> list[dict]:
    """The top row: one panel per aggregate, a bar (the interval) and a tick (the point) per
    agent and group; the rows drawn (panel, group, algo, y, point, lo, hi)."""
    algos = res.algos
    ypos = {a: len(algos) - 1 - i for i, a in enumerate(algos)}
    drawn = []
    for k, agg in enumerate(AGGREGATES):
        ax = fig.add_subplot(grid[0, k])
        for group in groups:
            rows = res.intervals[(res.intervals["group"] == group) & (res.intervals["aggregate"] == agg)]
            for r in rows.itertuples(index=False):
                y = ypos[r.algo] + offset[group]
                _interval_mark(ax, y, r, colors.color(r.algo), group)
                drawn.append((agg, group, r.algo, y, r.point, r.lo, r.hi))
        gap_scale(ax)
        _headroom_lines(ax, headroom, agg)
        ax.set_yticks(list(ypos.values()), [_agent_label(res, a, names) for a in ypos] if k == 0 else [""] * len(ypos))
        ax.set_ylim(-0.6, len(algos) - 0.4)
        ax.set_title(AGGREGATE_LABELS[agg] + (" (lower is better)" if agg == "optimality_gap" else ""), fontsize=10)
        ax.set_xlabel("share of the never → planner gap", fontsize=8)
        ax.grid(axis="x", alpha=0.3)
    return drawn


def _interval_mark(ax, y: float, r, color: str, group: str) -> None:
    """One agent's interval (a bar, none without one) and point estimate (a black tick) at ``y``."""
    if np.isfinite(r.lo):
        bars = ax.barh(
            y, r.hi - r.lo, left=r.lo, height=0.32, color=color, edgecolor=color, lw=0.8, **_GROUP_STYLE[group]
        )
        # a bar's ends are "sticky" to autoscaling: the panel's edge fell exactly on the
        # widest interval's end, which then read as cut off; with a margin beyond every end,
        # each interval is seen to end where it ends
        for bar in bars:
            bar.sticky_edges.x.clear()
    ax.plot([r.point, r.point], [y - 0.17, y + 0.17], solid_capstyle="butt", dash_capstyle="butt", **_TICK_STYLE[group])


def _profile_panel(ax, res: AggregateResult, group: str, colors: Palette, names, j: int):
    """The performance profile of one group: a line (and band) per agent; the axes."""
    from matplotlib.ticker import MaxNLocator

    algos = res.algos
    prof = res.profiles[res.profiles["group"] == group]
    for algo in algos:
        p = prof[prof["algo"] == algo]
        if p.empty:
            continue
        color = colors.color(algo)
        every = max(1, len(p) // 6)
        line = dict(color=color, lw=1.5, label=names[algo], marker=colors.marker(algo), ms=5)
        ax.plot(p["tau"], p["fraction"], markevery=(algos.index(algo) * every // len(algos), every), **line)
        if p["lo"].notna().any():
            ax.fill_between(p["tau"], p["lo"], p["hi"], color=color, alpha=0.15, lw=0)
    gap_scale(ax)
    ax.set_ylim(-0.02, 1.02)
    ax.set_title(f"performance profile, {group_title(res, group)}", fontsize=9)
    ax.set_xlabel("score threshold τ (share of the gap)", fontsize=8)
    if j == 0:
        ax.set_ylabel("fraction of runs with score > τ", fontsize=8)
    ax.xaxis.set_major_locator(MaxNLocator(6))
    ax.grid(alpha=0.3)
    if prof.empty:
        ax.text(
            0.5, 0.5, "no scored regime in this group", ha="center", va="center", transform=ax.transAxes, fontsize=8
        )
    return ax


def _improvement_panel(fig: Figure, ax, res: AggregateResult, group: str, colorbar: bool) -> None:
    """The matrix of P(row > column) of one group, each cell written in it."""
    algos = res.algos
    mat = np.full((len(algos), len(algos)), np.nan)
    idx = {a: i for i, a in enumerate(algos)}
    for r in res.improvement[res.improvement["group"] == group].itertuples(index=False):
        mat[idx[r.x], idx[r.y]] = r.p
    im = ax.imshow(mat, cmap="RdBu", vmin=0, vmax=1)
    for (i, k), v in np.ndenumerate(mat):
        if np.isfinite(v):
            ax.text(k, i, f"{v:.2f}", ha="center", va="center", fontsize=8, color="w" if abs(v - 0.5) > 0.3 else "k")
    labels = [algo_label(a) for a in algos]
    ax.set_xticks(range(len(algos)), labels, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(len(algos)), labels, fontsize=8)
    ax.set_title(f"P(row > column), {group_title(res, group)}", fontsize=9)
    if colorbar:
        fig.colorbar(im, ax=ax, shrink=0.8, label="probability of improvement")


def _aggregate_legend(fig: Figure, res: AggregateResult, names, profile_axes, groups, offset) -> None:
    """The legend: every agent drawn in either profile (one of the delayed regimes alone is in
    the second only) and the references, then a row saying which row and tick is which group."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    found = legend_entries(profile_axes)
    labels = [names[a] for a in res.algos if names[a] in found]
    h0, l0 = fig.axes[0].get_legend_handles_labels()  # the references above the planner, if drawn
    bars = [Patch(facecolor="0.5", edgecolor="0.4", **_GROUP_STYLE[g]) for g in groups]
    ticks = [Line2D([], [], marker="|", ms=0, **_TICK_STYLE[g]) for g in groups]
    agents = ([found[lab] for lab in labels] + h0, labels + l0)
    legend_rows(fig, [agents, (list(zip(bars, ticks)), [_group_entry(res, g, offset[g]) for g in groups])])


def _aggregate_caption(res: AggregateResult, ev: pd.DataFrame | None, headroom: pd.DataFrame | None) -> str:
    """What a score is, how many seeds, how the intervals were made, what the grey lines are."""
    n_runs = res.scores.groupby(["regime", "algo"]).size() if not res.scores.empty else pd.Series(dtype=int)
    runs_text = count_span(n_runs) if len(n_runs) else "0"
    caption = (
        "score of a run (one seed on one regime) = share of the regime's never → planner gap it closes on its own evaluation days "
        "(0 % = never eat, 100 % = the greedy full-information planner);\n"
        f"per agent over regimes x seeds ({runs_text} seeds per regime); bars = 95 % intervals over runs "
        f"(IQM: {interval_caption('iqm')};\n{aggregate_intervals_text()}; none drawn), "
        "black tick = point estimate (rliable.metrics); dotted: never (0 %), planner (100 %)"
    )
    if headroom is not None and not headroom[headroom["group"] == "all"].empty:
        caption += (
            ";\ngrey dashed / solid (IQM, median, mean): lookahead / clairvoyant, the references above the planner, "
            "the same aggregate of their runs over all regimes on the same days"
        )
    if ev is not None and not ev.empty:
        caption += f"\n{budget_seeds_line(ev)}"
    return caption


def aggregate_intervals_text(profile: bool = True) -> str:
    """How the intervals of the median, mean, optimality gap, P(X > Y) (and the profiles'
    bands) are made, with their measured coverage, for a caption."""
    named = {"median": "median", "mean": "mean", "gap": "optimality gap", "improvement": "P(X > Y)"}
    if profile:
        named["profile"] = "profile bands"
    return "; ".join(f"{name}: {aggregate_caption(statistic)}" for statistic, name in named.items())


def _group_entry(res: AggregateResult, group: str, offset: float) -> str:
    """The legend entry of one group of regimes: which of each agent's two rows (upper or
    lower) and which tick (solid or dotted) is it, so that a figure of ticks alone (one seed)
    reads too: ``all regimes (run0-6): upper row, solid tick, solid bar``."""
    place = _PLACE.get(offset, "")
    tick = "solid" if group == "all" else "dotted"
    bar = "hatched bar" if _GROUP_STYLE[group]["hatch"] else "solid bar"
    return f"{group_title(res, group)}: " + ", ".join(
        p for p in (f"{place} row" if place else "", f"{tick} tick", bar) if p
    )


def _agent_label(res: AggregateResult, algo: str, names: dict[str, str] | None = None) -> str:
    """The agent's legend label (``names``, else its name), flagged with its own regimes when
    it lacks some the others have."""
    own = next((by[algo] for by in res.partial.values() if algo in by), None)
    return (names or {}).get(algo, algo_label(algo)) + (f"\n(own regimes: {regime_span(own)})" if own else "")


def _width_notes(res: AggregateResult) -> list[str]:
    """Why some agents have no bar or a bar of no width: one seed per regime leaves nothing to
    resample (no interval, the tick alone); seeds that all score alike give every resample the
    same value (an interval of zero width)."""
    iv = res.intervals[res.intervals["aggregate"] == "iqm"]
    mine = {a: iv[iv["algo"] == a] for a in res.algos if (iv["algo"] == a).any()}
    single = [a for a, m in mine.items() if m["lo"].isna().all()]
    flat = [a for a, m in mine.items() if a not in single and np.allclose(m["hi"], m["lo"], equal_nan=True)]
    notes = []
    if single:
        notes.append(
            f"{', '.join(algo_label(a) for a in single)}: one seed per regime, so no interval (nothing to resample): "
            "the black tick alone is drawn; run more seeds (e.g. --seeds paper) for a bar"
        )
    if flat:
        notes.append(
            f"{', '.join(algo_label(a) for a in flat)}: every resample of the seeds gives the same IQM, so the "
            "interval has zero width (the seeds scored alike)"
        )
    return notes


# --------------------------------------------------------------------------- table
def aggregate_table(res: AggregateResult, ev: pd.DataFrame | None = None) -> TableResult:
    """One row per group and agent: the four aggregates (in % of the gap) with their 95 %
    intervals and P(this agent > each other agent) with its interval. ``raw`` has the numbers
    (columns ``<aggregate>``, ``<aggregate>_lo``, ``_hi``, ``p_gt_<algo>``, ...).

    ``ev``: the evaluation episodes the scores came from: each row then states its agent's
    training budget (days) and the caption the budgets and seeds (a warning when they differ)."""
    budgets = {a: budget_cell(ev[ev["algo"] == a]) for a in res.algos} if ev is not None and not ev.empty else {}
    groups = [g for g in GROUPS if res.regimes.get(g) or res.partial.get(g)]
    pairs = [pair for group in groups for pair in _aggregate_rows(res, group, budgets)]
    title = (
        "Aggregate scores: share of the never -> planner gap per run (seed x regime), over regimes x seeds; point estimate "
        f"[95 % interval over runs: IQM {interval_caption('iqm')}; {aggregate_intervals_text(profile=False)}; none "
        "drawn]; P(> Y): probability that a run of the row's agent scores above a run of Y on the same regime, averaged "
        "over regimes"
    )
    if budgets:
        title += f"; {budget_caption(ev)}"
    budget_col = ["budget (days)"] if budgets else []
    cols = ["regimes", "algorithm", *budget_col, "runs", *(f"{AGGREGATE_LABELS[a]} (%)" for a in AGGREGATES)]
    cols += [f"P(> {algo_label(a)})" for a in res.algos]
    fmt = pd.DataFrame([f for _, f in pairs], columns=cols).astype(object).fillna("")  # a column all None is float64
    if len(fmt) == 0:
        fmt = fmt[cols[: 3 + len(budget_col)]]
    raw_cols = ["group", "regimes", "algo", *(["budget"] if budgets else []), "runs"]
    raw_cols += [f"{a}{s}" for a in [*AGGREGATES, *(f"p_gt_{o}" for o in res.algos)] for s in ("", "_lo", "_hi")]
    return TableResult("aggregate", title, pd.DataFrame([r for r, _ in pairs], columns=raw_cols), fmt).add_notes(
        res.notes
    )


def _aggregate_rows(res: AggregateResult, group: str, budgets: dict[str, str]):
    """(raw row, formatted row) of each agent of one group of regimes."""
    iv = res.intervals[res.intervals["group"] == group]
    imp = res.improvement[res.improvement["group"] == group]
    for algo in res.algos:
        mine = iv[iv["algo"] == algo].set_index("aggregate")
        if mine.empty:
            continue
        regimes = ",".join(res.partial.get(group, {}).get(algo) or res.regimes[group])
        row = {"group": group, "regimes": regimes, "algo": algo, "runs": int(mine["runs"].iloc[0])}
        f = {"regimes": group_title(res, group, algo), "algorithm": algo_label(algo), "runs": row["runs"]}
        if budgets:
            row["budget"] = f["budget (days)"] = budgets.get(algo, "?")
        for agg in AGGREGATES:
            p, lo, hi = (float(mine.loc[agg, c]) for c in ("point", "lo", "hi"))
            row[agg], row[f"{agg}_lo"], row[f"{agg}_hi"] = p, lo, hi
            f[f"{AGGREGATE_LABELS[agg]} (%)"] = interval_cell(p, lo, hi, lambda v: f"{100 * v:.0f}")  # no % sign
        for other in [o for o in res.algos if o != algo]:
            r = imp[(imp["x"] == algo) & (imp["y"] == other)]
            p, lo, hi = (float(r[c].iloc[0]) if len(r) else float("nan") for c in ("p", "lo", "hi"))
            row[f"p_gt_{other}"], row[f"p_gt_{other}_lo"], row[f"p_gt_{other}_hi"] = p, lo, hi
            f[f"P(> {algo_label(other)})"] = interval_cell(p, lo, hi)
        yield row, f
