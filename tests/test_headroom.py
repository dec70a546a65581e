"""The lookahead and clairvoyant references beside the agents (issue 73): their shares in the
results table, Figure 3, Figure 5 and the leaderboard."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest


def _frames():
    """Two agents' evaluation days on run0 and run3 (seeds 0, 21; 2 days each) and the day
    yardsticks with lookahead and clairvoyant: never -20, planner -4, lookahead -2.4 (110 %),
    clairvoyant -1.6 (115 %) on every day."""
    from tests.test_report_builders import synthetic

    df = synthetic(regimes=("run0", "run3"), algos=("ppo", "gru_ppo"), seeds=(0, 21), eval_eps=2, train_eps=1)
    df["job_id"] = df.groupby(["regime", "algo", "seed"]).ngroup()
    df["budget"], df["algo_version"] = 5000, 1
    ev = df[df.phase == "eval"]
    refs = (
        ev[["regime", "seed", "episode"]]
        .drop_duplicates()
        .assign(never=-20.0, planner=-4.0, lookahead=-2.4, clairvoyant=-1.6)
    )
    return df, ev, refs


def test_the_results_table_gives_the_references_shares_beside_each_agent():
    from nutribench.report.tables import table_results

    df, _, refs = _frames()
    t = table_results(df, seeds_bootstrap=50, references=refs)
    assert t.raw["lookahead_gap"].to_numpy() == pytest.approx(1.1)
    assert t.raw["clairvoyant_gap"].to_numpy() == pytest.approx(1.15)
    assert set(t.formatted["lookahead / clairvoyant"]) == {"110 % / 115 %"}
    assert "100 % is the greedy planner, not the optimum" in t.title
    # a day the committed file lacks: no share rather than one of other days
    gap = refs.copy()
    gap.loc[gap.index[0], "lookahead"] = np.nan
    t = table_results(df, seeds_bootstrap=50, references=gap)
    assert t.formatted.iloc[0]["lookahead / clairvoyant"] == "n/a / 115 %"
    # without them, the table is as it was
    assert (
        "lookahead / clairvoyant"
        not in table_results(df, references=refs[["regime", "seed", "episode", "never", "planner"]]).formatted
    )


def test_figure_3_draws_the_references_above_the_planner_on_panel_a():
    from nutribench.report.figures import eval_across_regimes

    df, _, refs = _frames()
    res = eval_across_regimes(df, day_references=refs, bootstrap=50)
    panel = res.figure.axes[0]
    lines = {line.get_label(): line for line in panel.get_lines()}
    for policy, share in (("lookahead", 1.1), ("clairvoyant", 1.15)):
        y = np.asarray(lines[f"{policy} (reference)"].get_ydata(), dtype=float)
        assert list(y[np.isfinite(y)]) == pytest.approx([share, share])  # run0, run3 (broken between: none ran run1-2)
    assert "references above the planner" in res.figure._suptitle.get_text()
    # the other panels have no gap scale: no such line there
    assert not any("lookahead" in line.get_label() for ax in res.figure.axes[1:4] for line in ax.get_lines())


def test_figure_5_and_the_leaderboard_set_the_references_beside_the_agents():
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_figure
    from nutribench.report.headroom import aggregate_points
    from nutribench.report.leaderboard import REFERENCE_PROTOCOL, leaderboard_rows, leaderboard_table

    _, ev, refs = _frames()
    res = aggregate_from_eval(ev, refs, reps=50)
    points = aggregate_points(ev, refs, res.regimes)
    assert set(points["policy"]) == {"lookahead", "clairvoyant"}
    assert points[(points.group == "all") & (points.policy == "lookahead")]["point"].to_numpy() == pytest.approx(1.1)
    fig = aggregate_figure(res, ev=ev, headroom=points).figure
    for ax in fig.axes[:3]:  # IQM, median, mean
        xs = {line.get_label(): line.get_xdata()[0] for line in ax.get_lines() if "(reference)" in line.get_label()}
        assert xs == pytest.approx({"lookahead (reference)": 1.1, "clairvoyant (reference)": 1.15})
    jobs = pd.DataFrame({"id": sorted(ev["job_id"].unique()), "engine": "sb3", "nutribench_version": "0.1.0"})
    jobs["git_commit"], jobs["git_dirty"] = "abcdef0123", False
    rows = leaderboard_rows(ev, refs, jobs, {"ppo": "paper config", "gru_ppo": "paper config"}, reps=50)
    assert list(rows["algo"])[-2:] == ["lookahead", "clairvoyant"]
    assert rows["rank"].iloc[-2:].isna().all() and list(rows["rank"].iloc[:2]) == [1, 2]
    ref = rows.set_index("algo")
    assert ref.loc["clairvoyant", "iqm"] == pytest.approx(1.15) and ref.loc["lookahead", "share_run3"] == pytest.approx(
        1.1
    )
    assert ref.loc["lookahead", "protocol"] == REFERENCE_PROTOCOL
    md = leaderboard_table(rows).to_markdown()
    assert "| | lookahead | 110 [" in md.replace("|  |", "| |") and "| - | from regimes/references.csv" in md
