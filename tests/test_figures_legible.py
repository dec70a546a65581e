"""Figures a reader can read without the code (issue 54): each agent's budget and seed count in
its legend entry when the agents drawn differ in them, user colours apart from the five (also
under simulated colour-vision deficiencies) with a marker per agent as a second cue, Figure 5's
two ticks per agent named, Figure 1's dashed line explained, and the HTML page's short
table headings. Checked through what the builders drew, not through pixels."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest

from nutribench.report.palette import (
    BUILTIN_COLORS,
    BUILTIN_ORDER,
    USER_COLORS,
    USER_MIN_DE2000,
    USER_MIN_DE2000_CVD,
    USER_MIN_DISTANCE,
    colors,
    distance,
    lab,
    palette,
)
from tests.test_newcomer import _as_seen
from tests.test_report_builders import _day_refs, synthetic

PAPER = (0, 21, 9, 2003, 1997)
USERS = ("trpo_mine_tuned", "mine", "qrdqn_mine", "reinforce_loop")


def legend_texts(fig) -> list[str]:
    return [t.get_text() for leg in fig.legends for t in leg.get_texts() if t.get_text()]


def mixed() -> pd.DataFrame:
    """PPO on the paper's five seeds for 5000 days, a user's agent on one seed for 20."""
    ppo = synthetic(regimes=("run0", "run3"), algos=("ppo",), seeds=PAPER, train_eps=30).assign(budget=5000)
    mine = synthetic(regimes=("run0", "run3"), algos=("trpo_mine_tuned",), seeds=(0,), train_eps=20, seed=1)
    return pd.concat([ppo, mine.assign(budget=20)], ignore_index=True)


# --------------------------------------------------------------------------- budgets in the legend
def test_legend_entries_state_each_agents_budget_and_seed_count_when_they_differ():
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_figure
    from nutribench.report.figures import eval_across_regimes, training_curves

    df = mixed()
    ev = df[df.phase == "eval"]
    fig1 = training_curves(df, "return")
    fig3 = eval_across_regimes(df, bootstrap=100)
    fig5 = aggregate_figure(aggregate_from_eval(ev, _day_refs(df), reps=100), ev=ev)
    for res in (fig1, fig3, fig5):
        texts = legend_texts(res.figure)
        assert "PPO (5000 days)" in texts, texts  # five seeds: no count
        assert "trpo_mine_tuned (20 days, 1 seed)" in texts, texts
        title = res.figure.get_suptitle()
        assert "trpo_mine_tuned: budget" not in title and "budgets 20, 5000 days" in title
    # the lines carry the same labels as the legend (Figures 1 and 3 draw them)
    assert {ln.get_label() for ln in fig3.figure.axes[0].get_lines()} >= {
        "PPO (5000 days)",
        "trpo_mine_tuned (20 days, 1 seed)",
    }
    # Figure 5 names the agents on its rows the same way
    rows = [t.get_text() for t in fig5.figure.axes[0].get_yticklabels()]
    assert rows == ["PPO (5000 days)", "trpo_mine_tuned (20 days, 1 seed)"]


def test_alike_agents_keep_short_legend_entries_and_one_title_line():
    from nutribench.report.figures import training_curves

    df = synthetic(algos=("ppo", "sac"), seeds=(0, 1), train_eps=20).assign(budget=400)
    res = training_curves(df, "return")
    assert [t for t in legend_texts(res.figure) if not t.startswith("best")] == ["PPO", "SAC"]
    assert "budget 400 days, seeds 0, 1" in res.figure.get_suptitle()


# --------------------------------------------------------------------------- colours and markers
def distance2000(a: str, b: str) -> float:
    """Perceptual distance of two colours (CIEDE2000), nearer to what a reader sees than CIE76,
    which overstates differences between saturated blues and greens: the measure
    :data:`~nutribench.report.palette.USER_COLORS` were chosen by, checked here."""
    (l1, a1, b1), (l2, a2, b2) = lab(a), lab(b)
    cbar = (np.hypot(a1, b1) + np.hypot(a2, b2)) / 2
    g = 0.5 * (1 - np.sqrt(cbar**7 / (cbar**7 + 25.0**7)))
    a1, a2 = (1 + g) * a1, (1 + g) * a2
    c1, c2 = np.hypot(a1, b1), np.hypot(a2, b2)
    h1, h2 = np.degrees(np.arctan2(b1, a1)) % 360, np.degrees(np.arctan2(b2, a2)) % 360
    dh = 0.0 if c1 * c2 == 0 else (h2 - h1 + 180) % 360 - 180
    d_h = 2 * np.sqrt(c1 * c2) * np.sin(np.radians(dh / 2))
    lbar, cbar_p = (l1 + l2) / 2, (c1 + c2) / 2
    hbar = h1 + h2 if c1 * c2 == 0 else ((h1 + h2) / 2 + (180 if abs(h1 - h2) > 180 else 0)) % 360
    t = (
        1
        - 0.17 * np.cos(np.radians(hbar - 30))
        + 0.24 * np.cos(np.radians(2 * hbar))
        + 0.32 * np.cos(np.radians(3 * hbar + 6))
        - 0.20 * np.cos(np.radians(4 * hbar - 63))
    )
    s_l = 1 + 0.015 * (lbar - 50) ** 2 / np.sqrt(20 + (lbar - 50) ** 2)
    s_c, s_h = 1 + 0.045 * cbar_p, 1 + 0.015 * cbar_p * t
    r_t = -2 * np.sqrt(cbar_p**7 / (cbar_p**7 + 25.0**7)) * np.sin(np.radians(60 * np.exp(-(((hbar - 275) / 25) ** 2))))
    dl, dc, dh_ = (l2 - l1) / s_l, (c2 - c1) / s_c, d_h / s_h
    return float(np.sqrt(dl**2 + dc**2 + dh_**2 + r_t * dc * dh_))


def test_five_and_four_users_stay_apart_also_under_colour_vision_deficiencies():
    chosen = colors([*BUILTIN_ORDER, *USERS])
    assert {n: chosen[n] for n in BUILTIN_ORDER} == BUILTIN_COLORS  # the paper's colours kept
    users = [chosen[n] for n in USERS]
    assert sorted(users) == sorted(USER_COLORS)
    pairs = [(u, b) for u in users for b in BUILTIN_COLORS.values()] + list(itertools.combinations(users, 2))
    for a, b in pairs:
        assert distance(a, b) >= USER_MIN_DISTANCE, (a, b)
        assert distance2000(a, b) >= USER_MIN_DE2000, (a, b)
        for kind in ("deutan", "protan"):
            seen = distance2000(_as_seen(a, kind), _as_seen(b, kind))
            assert seen >= USER_MIN_DE2000_CVD, (a, b, kind, seen)
    assert USER_MIN_DISTANCE > 32  # the old bar, raised
    # Tol's teal, the first user colour before, was nearer PPO's green than the bar now allows
    assert distance2000("#44aa99", BUILTIN_COLORS["ppo"]) < USER_MIN_DE2000


def test_distance2000_is_zero_for_one_colour_symmetric_and_tighter_than_cie76_on_blues():
    assert distance2000("#1f77b4", "#1f77b4") == pytest.approx(0.0)
    assert distance2000("#1f77b4", "#9467bd") == pytest.approx(distance2000("#9467bd", "#1f77b4"))
    assert distance2000("#0000ff", "#1f77b4") < distance("#0000ff", "#1f77b4") / 2


def test_each_agent_has_its_own_marker_the_same_in_every_figure():
    from nutribench.report.figures import eval_across_regimes, training_curves

    pal = palette([*BUILTIN_ORDER, *USERS])
    marks = {n: pal.marker(n) for n in [*BUILTIN_ORDER, *USERS]}
    assert len(set(marks.values())) == len(marks)
    assert not set(marks.values()) & {"x", ".", "+", "*"}  # the reference lines' markers
    df = synthetic(regimes=("run0", "run3"), algos=("ppo", "mine", "sac"), seeds=(0, 1), train_eps=20)
    drawn = {}
    for res in (training_curves(df, "return", colors=pal), eval_across_regimes(df, colors=pal, bootstrap=50)):
        for ln in res.figure.axes[0].get_lines():
            if ln.get_label() in ("PPO", "SAC", "mine"):
                drawn.setdefault(ln.get_label(), set()).add(ln.get_marker())
    assert drawn == {"PPO": {marks["ppo"]}, "SAC": {marks["sac"]}, "mine": {marks["mine"]}}


# --------------------------------------------------------------------------- Figure 5's ticks
def test_figure_5_with_one_seed_names_its_two_ticks_per_agent():
    from nutribench.report.aggregate import aggregate_from_eval
    from nutribench.report.aggregate_view import aggregate_figure

    df = synthetic(regimes=("run0", "run3"), algos=("ppo", "mine"), seeds=(0,), train_eps=1)
    ev = df[df.phase == "eval"]
    res = aggregate_figure(aggregate_from_eval(ev, _day_refs(df), reps=100), ev=ev)
    iqm = res.data[res.data.panel == "iqm"]
    assert iqm["lo"].isna().all()  # one seed: ticks alone
    for _, per in iqm.groupby("algo"):
        y = per.set_index("group")["y"]
        assert y["all"] > y["delayed"]  # all regimes above, delayed below
    texts = legend_texts(res.figure)
    (all_entry,) = [t for t in texts if t.startswith("all regimes")]
    (delayed_entry,) = [t for t in texts if t.startswith("delayed regimes")]
    assert "upper row" in all_entry and "solid tick" in all_entry
    assert "lower row" in delayed_entry and "dotted tick" in delayed_entry
    # and the ticks drawn do differ as the legend says
    ticks = [ln for ln in res.figure.axes[0].get_lines() if ln.get_color() == "k" and len(ln.get_xdata()) == 2]
    styles = {float(np.mean(ln.get_ydata())) % 1: ln.get_linestyle() for ln in ticks}
    assert set(styles.values()) == {"-", ":"}


# --------------------------------------------------------------------------- Figure 1's dashed line
def test_figure_1_legend_says_what_the_dashed_line_is():
    from nutribench.report.figures import training_curves

    df = synthetic(algos=("ppo", "sac"), seeds=(0, 1), train_eps=30)
    res = training_curves(df, "return", window=5)
    (entry,) = [t for t in legend_texts(res.figure) if t.startswith("best")]
    assert entry == "best (smoothed): highest point of any line in its panel"
    for ax in res.figure.axes:
        if not ax.get_visible():
            continue
        (best,) = [ln for ln in ax.get_lines() if ln.get_label().startswith("best")]
        regime = ax.get_title()
        assert best.get_ydata()[0] == pytest.approx(res.data.loc[res.data.regime == regime, "mean"].max())


# --------------------------------------------------------------------------- the HTML page
def test_the_page_gives_a_table_a_short_heading_and_its_caption_beneath(tmp_path):
    from nutribench.report.html import page_html, page_table
    from nutribench.report.tables import TableResult

    title = "Leaderboard: every agent ranked by the IQM of its run scores (one seed on one regime = one run)"
    board = TableResult("leaderboard", title, pd.DataFrame(), pd.DataFrame({"agent": ["PPO"]}))
    item = page_table("leaderboard", board, [tmp_path / "leaderboard.md"])
    assert item.title == "Leaderboard" and item.caption == title
    page = page_html([item])
    assert "<h2>Leaderboard</h2>" in page and f'<p class="caption">{title}</p>' in page
    # a caption with no short head: the file stem
    plain = TableResult("x", "a caption without a head", pd.DataFrame(), pd.DataFrame())
    assert page_table("table_results", plain, []).title == "Table results"


def test_past_the_four_user_colours_the_markers_keep_every_agent_apart():
    """The colour guarantee (apart for normal vision and under deutan/protan) covers four user
    agents (USER_COLORS); with eight, the derived colours still differ for normal vision
    (CIE76 >= 32) and every agent keeps a marker of its own, the second cue where two
    colours look alike to a colour-blind reader."""
    users = (*USERS, "ppo_lr3e4", "sac_mine", "a2c_mine", "zz_last")
    names = [*BUILTIN_ORDER, *users]
    chosen = colors(names)
    pal = palette(names)
    assert len(set(chosen.values())) == len(names)
    for a, b in itertools.combinations(chosen.values(), 2):
        assert distance(a, b) >= 32, (a, b)
    assert len({pal.marker(n) for n in names}) == len(names)
