"""Figures that misstated what they drew (issue 75): Figure 5's legend names every agent of
either profile; Figure 3 draws no line across regime numbers nobody ran and keeps a lone
regime's points in the middle of its panel; Figure 5's intervals end inside their panels;
the trajectory view's legend keeps clear of its title. Checked through what was drawn
(lines, limits, extents), not through pixels."""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.backends.backend_agg import FigureCanvasAgg

from tests.test_figures_legible import legend_texts
from tests.test_report_builders import _day_refs, synthetic


def _recorded_beside_ppo() -> pd.DataFrame:
    """PPO on run0 and run3, and a recorded agent on run3 alone: it lacks a regime of the
    whole set (left out of that profile) but has every delayed one (drawn in that profile)."""
    ppo = synthetic(regimes=("run0", "run3"), algos=("ppo",), seeds=(0, 1, 2), train_eps=1)
    loop = synthetic(regimes=("run3",), algos=("reinforce_loop",), seeds=(0, 1, 2), train_eps=1, seed=3)
    return pd.concat([ppo, loop], ignore_index=True)


def test_figure_5_legend_names_an_agent_drawn_in_the_delayed_profile_only():
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_figure

    df = _recorded_beside_ppo()
    ev = df[df.phase == "eval"]
    res = aggregate_figure(aggregate_from_eval(ev, _day_refs(df), reps=100), ev=ev)
    drawn = {
        ln.get_label()
        for ax in res.figure.axes
        if ax.get_title().startswith("performance profile")
        for ln in ax.get_lines()
        if not ln.get_label().startswith("_")
    }
    assert any("reinforce_loop" in lab for lab in drawn), drawn  # drawn in the delayed profile
    assert drawn <= set(legend_texts(res.figure)), (drawn, legend_texts(res.figure))


def _segments(ax) -> list[tuple[float, float]]:
    """(x0, x1) of every line segment drawn between two finite points."""
    out = []
    for ln in ax.get_lines():
        x = np.asarray(ln.get_xdata(), dtype=float)
        y = np.asarray(ln.get_ydata(), dtype=float)
        for i in range(len(x) - 1):
            if ln.get_linestyle() != "None" and np.isfinite(x[i : i + 2]).all() and np.isfinite(y[i : i + 2]).all():
                out.append((x[i], x[i + 1]))
    return out


def test_figure_3_draws_no_line_across_regimes_nobody_ran():
    from nutribench.report.figures import eval_across_regimes

    df = synthetic(regimes=("run0", "run3", "run4"), algos=("ppo", "sac"), seeds=(0, 1, 2), train_eps=1)
    refs = pd.DataFrame(
        [
            {"regime": r, "policy": p, "return": v, "foods": 0.0, "final_distance": 3.0, "overshoot_ratio": 0.0}
            for r in ("run0", "run3", "run4")
            for p, v in (("never", -20.0), ("planner", -4.0))
        ]
    )
    res = eval_across_regimes(df, references=refs, bootstrap=50)
    for ax in res.figure.axes:
        spans = [abs(b - a) for a, b in _segments(ax)]
        assert spans, ax.get_title()  # run3 -> run4 is still joined
        assert max(spans) < 1.5, (ax.get_title(), spans)  # never run0 -> run3
    # the two neighbours keep their line and band; the lone run0 point its error bar
    assert res.data[(res.data.panel == "return") & (res.data.algo == "ppo")]["x"].tolist() == [0, 3, 4]
    assert any(ax.collections for ax in res.figure.axes)


def test_figure_3_keeps_a_lone_regime_in_the_middle_of_its_panel():
    from nutribench.report.figures import eval_across_regimes

    df = synthetic(regimes=("run3",), algos=("ppo", "reinforce_loop"), seeds=(0, 1, 2), train_eps=1)
    res = eval_across_regimes(df, bootstrap=50)
    for ax in res.figure.axes:
        lo, hi = ax.get_xlim()
        xs = [x for ln in ax.get_lines() for x in np.asarray(ln.get_xdata(), dtype=float) if np.isfinite(x)]
        assert xs
        # before, the two dodged points (3 -/+ 0.03) were the panel's two edges
        assert min(xs) - lo > 0.4 and hi - max(xs) > 0.4, (lo, hi, xs)
    # and beside agents with more regimes, the one-regime agent sits at its regime
    both = pd.concat([synthetic(regimes=("run0", "run6"), algos=("ppo",), train_eps=1), df[df.algo != "ppo"]])
    res = eval_across_regimes(both, bootstrap=50)
    loop = res.data[(res.data.panel == "return") & (res.data.algo == "reinforce_loop")]
    assert loop["x"].tolist() == [3]
    lo, hi = res.figure.axes[0].get_xlim()
    assert lo < 0 - 0.4 and hi > 6 + 0.4


def test_figure_5_intervals_end_inside_their_panels():
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_figure

    df = synthetic(regimes=("run0", "run3"), algos=("ppo", "sac"), seeds=(0, 1, 2, 3), train_eps=1)
    ev = df[df.phase == "eval"]
    res = aggregate_figure(aggregate_from_eval(ev, _day_refs(df), reps=200), ev=ev)
    titles = {"IQM": "iqm", "median": "median", "mean": "mean", "optimality gap (lower is better)": "optimality_gap"}
    checked = 0
    for ax in res.figure.axes:
        panel = titles.get(ax.get_title())
        if panel is None:
            continue
        drawn = res.data[(res.data.panel == panel) & res.data["lo"].notna()]
        assert len(drawn)
        lo, hi = ax.get_xlim()
        margin = 0.01 * (hi - lo)
        # before, the widest interval's end was the panel's edge (read as cut off)
        assert lo < drawn["lo"].min() - margin and hi > drawn["hi"].max() + margin, (panel, lo, hi)
        checked += 1
    assert checked == 4


def test_trajectory_legend_keeps_clear_of_a_long_title():
    from nutribench.env import RegimeDynamics
    from nutribench.report.output import trajectory_figure

    H = 50
    eat = (np.arange(1, H + 1) % 7 == 0).astype(int)
    absorbed = np.cumsum(eat) * 0.1
    steps = pd.DataFrame(
        {
            "step": np.arange(1, H + 1),
            "food": np.arange(H) % 5,
            "action": eat,
            "C": absorbed,
            "F": absorbed,
            "P": absorbed,
        }
    )
    title = (
        "trpo_mine_tuned_with_a_long_name on run3, seed 1997, evaluation episode 12 (budget 5000 episodes): "
        "return -12.34, 7 meals"
    )
    fig = trajectory_figure(steps, RegimeDynamics("run3"), title=title)
    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)
    title_box = fig._suptitle.get_window_extent(renderer)
    (legend,) = fig.legends
    legend_box = legend.get_window_extent(renderer)
    assert not title_box.overlaps(legend_box), (title_box, legend_box)
    assert title_box.x1 <= fig.bbox.x1 and title_box.x0 >= fig.bbox.x0  # the whole title on the figure
