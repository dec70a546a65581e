"""Figure and table builders on synthetic DataFrames (no database)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from nutribench.config import list_regimes, load_env_config
from nutribench.report.figures import eval_across_regimes, training_curves
from nutribench.report.tables import table_regimes, table_results
from nutribench.stats import iqm, iqm_runs_ci, sem, t_intervals

METRICS = ["return", "foods", "final_distance", "overshoot_ratio"]


def synthetic(
    regimes=("run0", "run3", "run6"), algos=("ppo", "sac"), seeds=(0, 21, 9), train_eps=40, eval_eps=5, seed=0
):
    rng = np.random.default_rng(seed)
    rows = []
    for r in regimes:
        for a in algos:
            for s in seeds:
                for phase, n in (("train", train_eps), ("eval", eval_eps)):
                    for e in range(n):
                        rows.append(
                            {
                                "regime": r,
                                "algo": a,
                                "seed": s,
                                "phase": phase,
                                "episode": e,
                                "return": rng.normal(-100, 20),
                                "foods": rng.integers(0, 20),
                                "final_distance": rng.random() * 3,
                                "overshoot_ratio": rng.random(),
                            }
                        )
    return pd.DataFrame(rows)


def _lines(ax):
    return [l for l in ax.get_lines() if not l.get_label().startswith("best") and l.get_linestyle() != "--"]


def test_training_curves_panels_lines_and_band():
    df = synthetic()
    res = training_curves(df, "return", window=1)
    visible = [ax for ax in res.figure.axes if ax.get_visible()]
    assert len(visible) == 3
    for ax in visible:
        assert len(_lines(ax)) == 2  # one line per algorithm
        assert any(l.get_linestyle() == "--" for l in ax.get_lines())  # best-return line
    # with window 1 the band is the plain standard error across seeds, per episode
    cell = df[(df.phase == "train") & (df.regime == "run3") & (df.algo == "sac") & (df.episode == 7)]["return"]
    drawn = res.data[(res.data.regime == "run3") & (res.data.algo == "sac") & (res.data.episode == 7)].iloc[0]
    assert drawn["mean"] == pytest.approx(cell.mean())
    assert drawn["sem"] == pytest.approx(cell.std(ddof=1) / np.sqrt(3))


def test_training_curves_smoothing_window():
    df = synthetic(regimes=("run1",), algos=("ppo",), seeds=(0,))
    res = training_curves(df, "foods", window=5)
    train = df[df.phase == "train"].sort_values("episode")["foods"].to_numpy(dtype=float)
    np.testing.assert_allclose(res.data["mean"].to_numpy()[4], train[:5].mean())
    assert res.data["sem"].isna().all()  # one seed: no band
    assert len(res.figure.axes[0].collections) == 0


def test_missing_cells_are_omitted_and_noted():
    df = synthetic()
    df = df[~((df.regime == "run3") & (df.algo == "ppo"))]
    res = training_curves(df, "return")
    run3 = [ax for ax in res.figure.axes if ax.get_title() == "run3"][0]
    assert [l.get_label() for l in _lines(run3)] == ["SAC"]
    assert res.notes == ["no data: PPO/run3"]
    res3 = eval_across_regimes(df)
    ppo = res3.data[(res3.data.panel == "return") & (res3.data.algo == "ppo")]
    assert ppo["regime"].tolist() == ["run0", "run6"]


def test_eval_figure_four_panels_and_standard_error():
    df = synthetic()
    res = eval_across_regimes(df)
    assert len(res.figure.axes) == 4
    for ax in res.figure.axes:  # one line per algorithm (run0, run3, run6: broken between, so error bars too)
        assert [ln.get_label() for ln in ax.get_lines() if not ln.get_label().startswith("_")] == ["PPO", "SAC"]
    cell = df[(df.phase == "eval") & (df.regime == "run6") & (df.algo == "ppo")]["final_distance"]
    row = res.data[(res.data.panel == "final_distance") & (res.data.algo == "ppo") & (res.data.regime == "run6")].iloc[
        0
    ]
    assert row["mean"] == pytest.approx(cell.mean())
    assert row["sem"] == pytest.approx(cell.std(ddof=1) / np.sqrt(len(cell)))  # pooled, kept in the data
    assert row["lo"] <= row["mean"] <= row["hi"]  # the band drawn: 95 % interval over seeds
    assert row["x"] == 6


def test_eval_figure_with_references_and_algo_filter():
    df = synthetic(algos=("ppo", "gru_ppo", "sac"))
    refs = pd.DataFrame(
        [
            {"regime": r, "policy": p, **{m: v for m, v in zip(METRICS, (-50.0, 0.0, 3.0, 0.0))}}
            for r in ("run0", "run3", "run6")
            for p in ("never", "planner")
        ]
    )
    res = eval_across_regimes(df, algos=["ppo", "gru_ppo"], references=refs)
    assert sorted(res.data["algo"].unique()) == ["gru_ppo", "ppo"]
    labels = [l.get_label() for l in res.figure.axes[0].get_lines()]
    assert "never (reference)" in labels and "planner (reference)" in labels and "SAC" not in labels
    with pytest.raises(ValueError, match="no evaluation episodes"):
        eval_across_regimes(df, algos=["mc"])


def test_results_table_matches_pandas():
    df = synthetic()
    t = table_results(df)
    ev = df[df.phase == "eval"]
    g = ev.groupby(["regime", "algo"])
    for _, row in t.raw.iterrows():
        cell = g.get_group((row["regime"], row["algo"]))
        for m in METRICS:
            assert row[f"{m}_mean"] == pytest.approx(cell[m].mean())
            assert row[f"{m}_sem"] == pytest.approx(cell[m].sem())
        seed_means = cell.groupby("seed")["return"].mean().to_numpy()
        assert row["return_iqm"] == pytest.approx(iqm(seed_means))
        lo, hi = t_intervals(seed_means, "iqm")  # the IQM interval the statistics module chose
        assert (row["return_iqm_lo"], row["return_iqm_hi"]) == pytest.approx((lo[0], hi[0]))
        assert row["return_iqm_lo"] < row["return_iqm"] < row["return_iqm_hi"]
    md = t.to_markdown()
    assert md.count("\n| run") == 6 and "±" in md
    assert "\\pm" in t.to_latex()
    assert t.to_csv().splitlines()[0].startswith("regime,algo,seeds,episodes,return_mean")


def test_stats_helpers():
    assert iqm(np.arange(8.0)) == pytest.approx(np.mean([2, 3, 4, 5]))
    assert iqm(np.array([1.0, 100.0])) == pytest.approx(50.5)
    assert np.isnan(sem([1.0]))
    point, lo, hi = iqm_runs_ci([np.array([1.5])])  # one seed: no interval
    assert point == 1.5 and np.isnan(lo) and np.isnan(hi)


def test_table1_from_the_regime_files():
    t = table_regimes([load_env_config(r) for r in list_regimes()])
    assert t.raw["run"].tolist() == [f"run{k}" for k in range(7)]
    row = t.formatted.set_index("run").loc["run5"]
    assert row["tau_F"] == "18-20" and row["sigma_P"] == "2.8-4.8"


def test_eval_figure_draws_coinciding_algorithms_apart():
    df = synthetic()
    df.loc[df.phase == "eval", "return"] = -50.0  # both algorithms learned the same policy
    res = eval_across_regimes(df)
    ppo, sac = (l for l in _lines(res.figure.axes[0]) if not l.get_label().startswith("_"))
    np.testing.assert_array_equal(ppo.get_ydata(), sac.get_ydata())  # NaN where the line breaks
    px, sx = (np.asarray(ln.get_xdata(), dtype=float) for ln in (ppo, sac))
    px, sx = px[np.isfinite(px)], sx[np.isfinite(sx)]
    gap = sx - px
    assert (gap > 0).all() and np.allclose(gap, gap[0])
    centre = (px + sx) / 2
    assert np.allclose(centre, sorted(res.data["x"].unique()))


def test_training_table_is_the_last_tenth_of_training_beside_the_authors():
    from nutribench.report.tables import table_training

    df = synthetic(algos=("ppo", "sac"), train_eps=40).assign(budget=40)
    res = table_training(df)
    raw = res.raw.set_index(["regime", "algo"])
    tail = df[(df.phase == "train") & (df.episode >= 36)]
    for (regime, algo), cell in tail.groupby(["regime", "algo"]):
        per_seed = cell.groupby("seed")["return"].mean()
        assert raw.loc[(regime, algo), "return_mean"] == pytest.approx(per_seed.mean())
        assert raw.loc[(regime, algo), "return_sem"] == pytest.approx(per_seed.std(ddof=1) / np.sqrt(3))
    # the authors' logged numbers (nutribench/report/tables.py AUTHORS_LAST_10PCT), run0 and run6
    assert (raw.loc[("run0", "ppo"), "authors_return"], raw.loc[("run0", "ppo"), "authors_foods"]) == (-5.9, 5.0)
    assert (raw.loc[("run6", "sac"), "authors_return"], raw.loc[("run6", "sac"), "authors_foods"]) == (-29.0, 25.3)
    assert "authors' return" in res.formatted.columns


@pytest.mark.filterwarnings("error::RuntimeWarning")
def test_training_table_of_short_or_unfinished_jobs_holds_their_last_day_or_says_n_a():
    """Days are numbered from 0: a 1- or 5-day job's last tenth is its last day; a job still
    running (no day in its window yet) reads n/a, without numpy's empty-mean warning."""
    from nutribench.report.tables import table_training

    short = pd.concat(
        [
            synthetic(regimes=("run0",), algos=("ppo",), train_eps=1).assign(budget=1),
            synthetic(regimes=("run3",), algos=("ppo",), train_eps=5).assign(budget=5),
            synthetic(regimes=("run6",), algos=("ppo",), train_eps=30).assign(budget=5000),
        ]
    )
    res = table_training(short)
    raw = res.raw.set_index("regime")
    for regime, last in (("run0", 0), ("run3", 4)):
        day = short[(short.regime == regime) & (short.phase == "train") & (short.episode == last)]
        assert raw.loc[regime, "seeds"] == 3
        assert raw.loc[regime, "return_mean"] == pytest.approx(day["return"].mean())
    assert raw.loc["run6", "seeds"] == 0 and np.isnan(raw.loc["run6", "return_mean"])
    assert res.formatted.set_index("regime").loc["run6", "our return"] == "n/a"


def test_latex_escapes_every_special_character():
    from nutribench.report.tables import TableResult, latex_escape

    assert latex_escape("a_b 50% & #1 $x$ {y} ~z^2 \\ ±") == (
        r"a\_b 50\% \& \#1 \$x\$ \{y\} \textasciitilde{}z\textasciicircum{}2 \textbackslash{} $\pm$"
    )
    frame = pd.DataFrame({"name": ["ppo_#2 {v~1}"]})
    tex = TableResult("t", "title $", frame, frame).to_latex()
    assert r"ppo\_\#2 \{v\textasciitilde{}1\}" in tex and r"title \$" in tex


def test_the_best_line_says_smoothed_only_when_the_curves_are():
    """The caption and the legend agree on smoothing ("no smoothing" beside "best (smoothed)" would not)."""
    for window, label in ((1, "best"), (5, "best (smoothed)")):
        res = training_curves(synthetic(), "return", window=window)
        labels = [l.get_label() for ax in res.figure.axes for l in ax.get_lines()]
        assert label in labels and ("best (smoothed)" in labels) == (window > 1)


def _day_refs(df, never=-20.0, planner=-4.0):
    refs = df[df.phase == "eval"][["regime", "seed", "episode"]].drop_duplicates().copy()
    refs["never"], refs["planner"] = never, planner
    return refs


def test_the_return_panel_shows_the_share_of_the_gap_on_a_linear_axis():
    """Panel (A) shows each seed's share of the never -> planner gap closed, on a linear axis
    that says so; the simple policies' reference lines are on the same scale."""
    df = synthetic()
    refs = pd.DataFrame(
        [
            {"regime": r, "policy": p, "return": v, "foods": 0.0, "final_distance": 3.0, "overshoot_ratio": 0.0}
            for r in ("run0", "run3", "run6")
            for p, v in (("never", -20.0), ("planner", -4.0), ("always", -100.0))
        ]
    )
    res = eval_across_regimes(df, references=refs, day_references=_day_refs(df))
    ax = res.figure.axes[0]
    assert ax.get_yscale() == "linear" and "gap" in ax.get_title(loc="left") and "planner" in ax.get_ylabel()
    ev = df[df.phase == "eval"]
    cell = ev[(ev.regime == "run3") & (ev.algo == "sac")]
    shares = (cell.groupby("seed")["return"].mean() + 20.0) / 16.0
    row = res.data[(res.data.panel == "gap_closed") & (res.data.algo == "sac") & (res.data.regime == "run3")].iloc[0]
    assert row["mean"] == pytest.approx(shares.mean()) and row["lo"] <= row["mean"] <= row["hi"]
    always = [l for l in ax.get_lines() if l.get_label() == "always (reference)"][0]
    y = np.asarray(always.get_ydata(), dtype=float)
    assert np.isfinite(y).sum() == 3 and np.allclose(y[np.isfinite(y)], (-100.0 + 20.0) / 16.0)
    assert "share of the never -> planner gap" in res.figure._suptitle.get_text()
    # yardsticks missing on a regime's days: panel (A) falls back to returns, with a note
    res = eval_across_regimes(df, references=refs, day_references=_day_refs(df[df.regime != "run6"]))
    assert "return" in res.figure.axes[0].get_title(loc="left") and "(linear)" in res.figure.axes[0].get_ylabel()
    assert any("panel (A) shows returns" in n and "run6" in n for n in res.notes)
    assert set(res.data["panel"]) == {"return", "final_distance", "foods", "overshoot_ratio"}


def test_eval_bands_are_95_percent_intervals_over_seed_means():
    from nutribench.stats import mean_ci

    df = synthetic(seeds=(0, 1, 2, 3, 4))
    res = eval_across_regimes(df, bootstrap=500)
    ev = df[df.phase == "eval"]
    per_seed = ev[(ev.regime == "run0") & (ev.algo == "ppo")].groupby("seed")["foods"].mean().to_numpy(dtype=float)
    row = res.data[(res.data.panel == "foods") & (res.data.algo == "ppo") & (res.data.regime == "run0")].iloc[0]
    assert (row["mean"], row["lo"], row["hi"]) == pytest.approx(mean_ci(per_seed))
    from scipy import stats as sps

    # Student's t over the 5 seed means (the coverage simulation's choice), by hand
    half = sps.t.ppf(0.975, 4) * per_seed.std(ddof=1) / np.sqrt(5)
    assert (row["lo"], row["hi"]) == pytest.approx((per_seed.mean() - half, per_seed.mean() + half))
    assert row["seeds"] == 5
    band = res.figure.axes[2].collections[0].get_paths()[0].vertices[:, 1]
    assert np.isclose(band, row["lo"]).any() and np.isclose(band, row["hi"]).any()
    assert (
        "95 % interval over seeds of the seed means (t interval; simulated coverage" in res.figure._suptitle.get_text()
    )
    one = eval_across_regimes(synthetic(seeds=(0,)))
    assert one.data[["lo", "hi"]].isna().all().all() and "one seed: no band" in one.figure._suptitle.get_text()


def test_results_table_leads_with_the_seed_level_interval():
    from nutribench.stats import mean_ci

    df = synthetic()
    t = table_results(df, references=_day_refs(df))
    assert list(t.formatted.columns[5:7]) == [
        "return [95% CI over seeds]",
        "gap closed [95% CI over seeds]",
    ]  # after regime, algorithm, budget, seeds, episodes
    ev = df[df.phase == "eval"]
    per_seed = ev[(ev.regime == "run0") & (ev.algo == "ppo")].groupby("seed")["return"].mean().to_numpy(dtype=float)
    row = t.raw.iloc[0]
    assert (row["return_seed_mean"], row["return_seed_lo"], row["return_seed_hi"]) == pytest.approx(mean_ci(per_seed))
    assert (row["gap_closed_seed_mean"], row["gap_closed_seed_lo"]) == pytest.approx(
        mean_ci((per_seed + 20.0) / 16.0)[:2]
    )
    assert "±" in t.formatted.iloc[0]["return"]  # the paper's mean ± s.e. is kept beside it


def test_trajectory_meal_labels_sit_above_the_curves():
    """With many meals the labels stay out of the axes (inside, they would cover the curves)."""
    from nutribench.env import NutriRLEnv
    from nutribench.report.output import trajectory_figure

    env = NutriRLEnv("run3")
    env.reset(options={"foods": [k % 10 for k in range(50)]})
    rows = []
    for t in range(50):
        _, _, _, _, info = env.step(int(t % 3 == 0))
        s = info["state"]
        rows.append({"step": t + 1, "food": t % 10, "action": int(t % 3 == 0), "C": s[0], "F": s[1], "P": s[2]})
    fig = trajectory_figure(pd.DataFrame(rows), env.dyn, title="t")
    top = fig.axes[0]
    labels = [t for t in top.texts if t.get_rotation() == 90]
    assert len(labels) == 17
    for label in labels:  # y in axes coordinates, above the top of the axes
        assert label.get_transform() == top.get_xaxis_transform() and label.get_position()[1] > 1.0


def test_results_table_gives_the_share_of_the_never_to_planner_gap_on_the_rows_days():
    df = synthetic(regimes=("run0",), algos=("ppo",), seeds=(0, 21), eval_eps=2)
    ev = df[df.phase == "eval"]
    refs = ev[["regime", "seed", "episode"]].copy()
    refs["never"] = -20.0 - refs["episode"]  # -20, -21 per seed
    refs["planner"] = -4.0 + 0.0 * refs["episode"]
    t = table_results(df, references=refs)
    row = t.raw.iloc[0]
    assert row["never_mean"] == pytest.approx(-20.5) and row["planner_mean"] == pytest.approx(-4.0)
    assert row["gap_closed"] == pytest.approx((ev["return"].mean() + 20.5) / 16.5)
    assert t.formatted.iloc[0]["gap closed"] == f"{100 * row['gap_closed']:.0f} %"
    # a day without its yardsticks: no share rather than a share of other days
    t = table_results(df, references=refs.iloc[1:])
    assert np.isnan(t.raw.iloc[0]["gap_closed"]) and t.formatted.iloc[0]["gap closed"] == "n/a"
    # without references the table is as before
    assert "gap_closed" not in table_results(df).raw


def test_the_yardsticks_play_each_jobs_own_evaluation_days():
    from nutribench.agents import eval_food_streams
    from nutribench.baselines import play_simple_policy
    from nutribench.report.build import eval_day_references

    version = load_env_config("run3").version
    ev = pd.DataFrame(
        {
            "regime": ["run3"] * 3 + ["run0"],
            "regime_version": [version] * 3 + [version + 99],
            "seed": [9, 9, 9, 0],
            "episode": [0, 1, 2, 0],
        }
    )
    logged: list[str] = []
    refs = eval_day_references(ev, log=logged.append)
    assert list(refs["regime"]) == ["run3"] * 3 and list(refs["episode"]) == [
        0,
        1,
        2,
    ]  # run0's version is not the file's
    assert "run0" in logged[0] and f"v{version + 99}" in logged[0]
    streams = eval_food_streams("run3", 9, 3)
    for name in ("never", "planner"):
        assert list(refs[name]) == pytest.approx([r["return"] for r in play_simple_policy(name, "run3", streams)])
    assert (refs["planner"] > refs["never"]).all()
