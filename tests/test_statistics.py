"""Seed-level statistics: the aggregate scores against rliable, the stratified
bootstrap, the paired comparison against a hand computation, pairing by seed and day, and
``nutribench compare``'s one-line errors."""

from __future__ import annotations

import ast
import os
import re
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from rliable import metrics as rly
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.report.aggregate import (
    AGGREGATES,
    BATCHED,
    RLIABLE,
    aggregate_scores,
    improvement_probabilities,
    interval_estimates,
    performance_profiles,
    point_estimate,
    probability_of_improvement,
    run_scores,
    score_distribution,
    score_set,
    stratified_resamples,
)
from nutribench.report.aggregate_view import aggregate_figure, aggregate_table
from nutribench.report.compare import CompareError, compare_agents, paired_days
from tests.conftest import one_error_line

runner = CliRunner()

# A hand-made score matrix per agent: rows = runs (seeds), columns = regimes (tasks).
REGIMES = ["run0", "run1", "run2", "run3"]
SEEDS = [0, 9, 21, 1997, 2003]
MATRICES = {
    "mc": np.array(
        [
            [1.10, 0.62, 0.57, 0.29],
            [1.05, 0.70, 0.40, 0.35],
            [1.12, 0.55, 0.61, 0.10],
            [0.98, 0.66, 0.52, 0.31],
            [1.20, 0.58, 0.45, 0.27],
        ]
    ),
    "ppo": np.array(
        [
            [1.08, 0.00, -0.25, -0.88],
            [1.07, 0.10, -0.40, -0.60],
            [1.10, -0.20, 0.05, -1.20],
            [1.02, 0.30, -0.10, -0.95],
            [1.09, 0.05, -0.30, -0.70],
        ]
    ),
    "gru_ppo": np.array(
        [
            [1.10, 0.63, 0.42, 0.57],
            [1.06, 0.55, 0.48, 0.62],
            [1.11, 0.70, 0.39, 0.50],
            [1.09, 0.61, 0.45, 0.57],
            [1.03, 0.66, 0.36, 0.66],
        ]
    ),
}


def scores_frame(matrices=MATRICES, regimes=REGIMES, seeds=SEEDS) -> pd.DataFrame:
    rows = [
        {"regime": r, "algo": a, "seed": s, "score": float(m[i, j])}
        for a, m in matrices.items()
        for i, s in enumerate(seeds)
        for j, r in enumerate(regimes)
    ]
    return pd.DataFrame(rows)


# --------------------------------------------------------------------------- aggregates
def test_point_estimates_equal_rliable_on_a_hand_made_matrix():
    ss = score_set(scores_frame(), REGIMES)
    assert ss.regimes == REGIMES and not ss.notes
    for algo, m in MATRICES.items():
        np.testing.assert_array_equal(np.stack(ss.runs[algo], axis=1), m)  # runs x regimes, seeds in order
        iv = interval_estimates(ss, reps=200).set_index(["algo", "aggregate"])
        assert iv.loc[(algo, "iqm"), "point"] == pytest.approx(rly.aggregate_iqm(m), abs=1e-12)
        assert iv.loc[(algo, "median"), "point"] == pytest.approx(rly.aggregate_median(m), abs=1e-12)
        assert iv.loc[(algo, "mean"), "point"] == pytest.approx(rly.aggregate_mean(m), abs=1e-12)
        assert iv.loc[(algo, "optimality_gap"), "point"] == pytest.approx(
            rly.aggregate_optimality_gap(m, gamma=1), abs=1e-12
        )
        # the bootstrap's statistics, applied to the original sample, are rliable's too
        for agg in AGGREGATES:
            assert BATCHED[agg]([m[None, :, j] for j in range(m.shape[1])])[0] == pytest.approx(
                RLIABLE[agg](m), abs=1e-12
            )
    # one value by hand: 20 scores, IQM = mean of the 6th..15th smallest (scipy's 25 % trim)
    gru = np.sort(MATRICES["gru_ppo"].ravel())
    assert point_estimate("iqm", ss.runs["gru_ppo"]) == pytest.approx(gru[5:15].mean())
    assert point_estimate("optimality_gap", ss.runs["gru_ppo"]) == pytest.approx(1 - np.minimum(gru, 1).mean())


def test_probability_of_improvement_equals_rliable_and_is_complementary():
    ss = score_set(scores_frame(), REGIMES)
    imp = improvement_probabilities(ss, reps=300).set_index(["x", "y"])
    for x in MATRICES:
        for y in MATRICES:
            if x == y:
                continue
            expected = rly.probability_of_improvement(MATRICES[x], MATRICES[y])
            assert imp.loc[(x, y), "p"] == pytest.approx(expected, abs=1e-12)
            assert imp.loc[(x, y), "p"] + imp.loc[(y, x), "p"] == pytest.approx(1)
            assert imp.loc[(x, y), "lo"] <= imp.loc[(x, y), "p"] <= imp.loc[(x, y), "hi"]
    # by hand, run0 alone: MC's 1.10 beats 3 of GRU-PPO's 5 runs and ties one (1.10), 1.05 beats
    # 1, 1.12 and 1.20 beat all 5, 0.98 none: 14.5 of 25 pairs
    assert probability_of_improvement([MATRICES["mc"][:, 0]], [MATRICES["gru_ppo"][:, 0]]) == pytest.approx(14.5 / 25)


def test_ragged_runs_generalise_rliable():
    """A regime with fewer seeds: no rliable matrix; IQM/gap over the pooled runs, mean and
    median over the regimes' means, P(X > Y) per regime over its pairs."""
    df = scores_frame()
    df = df[~((df["regime"] == "run3") & df["seed"].isin([1997, 2003]))]  # run3: 3 seeds for everyone
    ss = score_set(df, REGIMES)
    runs = ss.runs["ppo"]
    assert [len(x) for x in runs] == [5, 5, 5, 3]  # no rliable matrix: not the same runs on every regime
    pooled = np.concatenate(runs)
    from scipy.stats import trim_mean

    assert point_estimate("iqm", runs) == pytest.approx(trim_mean(pooled, 0.25))
    assert point_estimate("mean", runs) == pytest.approx(np.mean([x.mean() for x in runs]))
    assert point_estimate("median", runs) == pytest.approx(np.median([x.mean() for x in runs]))
    per_task = [rly.probability_of_improvement(a[:, None], b[:, None]) for a, b in zip(ss.runs["mc"], ss.runs["ppo"])]
    assert probability_of_improvement(ss.runs["mc"], ss.runs["ppo"]) == pytest.approx(np.mean(per_task))


def test_stratified_bootstrap_redraws_runs_within_each_regime():
    runs = [np.array([1.0, 2.0, 3.0]), np.array([10.0, 20.0]), np.array([100.0])]
    res = stratified_resamples(runs, reps=500, rng=np.random.default_rng(0))
    assert [r.shape for r in res] == [(500, 3), (500, 2), (500, 1)]
    for orig, r in zip(runs, res):
        assert set(np.unique(r)) <= set(orig)  # never a run of another regime
    assert len({tuple(row) for row in res[0]}) > 10  # and really redrawn
    assert (res[2] == 100.0).all()


def test_intervals_are_deterministic_and_per_agent():
    df = scores_frame()
    a = aggregate_scores(df, reps=500, seed=3)
    b = aggregate_scores(df, reps=500, seed=3)
    pd.testing.assert_frame_equal(a.intervals, b.intervals)
    # an agent's interval does not depend on which other agents are in the report
    alone = aggregate_scores(df[df["algo"] == "mc"], reps=500, seed=3).intervals
    both = a.intervals[a.intervals["algo"] == "mc"].reset_index(drop=True)
    pd.testing.assert_frame_equal(alone.reset_index(drop=True), both)
    iv = a.intervals
    assert (iv["lo"] <= iv["point"] + 1e-12).all() and (iv["point"] <= iv["hi"] + 1e-12).all()
    # groups: all four regimes, and the delayed run1-run3
    assert a.regimes == {"all": REGIMES, "delayed": ["run1", "run2", "run3"]}
    delayed = a.intervals[(a.intervals["group"] == "delayed") & (a.intervals["aggregate"] == "mean")].set_index("algo")
    assert delayed.loc["ppo", "point"] == pytest.approx(rly.aggregate_mean(MATRICES["ppo"][:, 1:]))


def test_single_seed_has_no_interval():
    df = scores_frame()
    res = aggregate_scores(df[df["seed"] == 0], reps=200)
    assert res.intervals["point"].notna().all() and res.intervals["lo"].isna().all()
    assert "single seed" in aggregate_table(res).to_markdown()


def test_performance_profile_counts_runs_above_tau():
    ss = score_set(scores_frame(), REGIMES)
    taus = np.array([-1.0, 0.0, 0.5, 1.0, 1.5])
    prof = performance_profiles(ss, taus, reps=200)
    for algo, m in MATRICES.items():
        got = prof[prof["algo"] == algo]["fraction"].to_numpy()
        np.testing.assert_allclose(got, [(m > t).mean() for t in taus])  # rliable's score distribution
    np.testing.assert_allclose(score_distribution(np.array([[0.1, 0.6, 0.9]]), np.array([0.5]))[0], [2 / 3])


def test_run_scores_share_of_the_gap_on_the_runs_own_days():
    ev = pd.DataFrame(
        {
            "regime": ["run1"] * 4 + ["run2"] * 2,
            "algo": ["ppo"] * 6,
            "seed": [0, 0, 1, 1, 0, 0],
            "episode": [0, 1, 0, 1, 0, 1],
            "phase": "eval",
            "return": [-10.0, -14.0, -20.0, -22.0, -5.0, -7.0],
        }
    )
    refs = pd.DataFrame(
        {
            "regime": ["run1"] * 4,
            "seed": [0, 0, 1, 1],
            "episode": [0, 1, 0, 1],
            "never": [-21.0, -22.0, -21.5, -21.5],
            "planner": [-4.0, -6.0, -5.0, -5.0],
        }
    )
    sc = run_scores(ev, refs).set_index(["regime", "seed"])
    # seed 0 of run1: return -12, never -21.5, planner -5 -> (−12 + 21.5) / 16.5
    assert sc.loc[("run1", 0), "score"] == pytest.approx(9.5 / 16.5)
    assert sc.loc[("run1", 1), "score"] == pytest.approx((-21 + 21.5) / 16.5)
    assert np.isnan(sc.loc[("run2", 0), "score"])  # no yardstick for run2
    ss = score_set(run_scores(ev, refs), ["run1", "run2"])
    assert ss.regimes == ["run1"]
    assert ss.notes and "run2 left out" in ss.notes[0] and "yardstick" in ss.notes[0]


def test_aggregate_figure_and_table_draw_what_was_computed(tmp_path: Path):
    res = aggregate_scores(scores_frame(), reps=300)
    fig = aggregate_figure(res)
    assert len(fig.figure.axes) >= 8  # 4 interval panels, 2 profiles, 2 matrices (+ colour bar)
    drawn = fig.data.set_index(["panel", "group", "algo"])
    iv = res.intervals.set_index(["aggregate", "group", "algo"])
    assert drawn.loc[("iqm", "all", "gru_ppo"), "point"] == iv.loc[("iqm", "all", "gru_ppo"), "point"]
    fig.figure.savefig(tmp_path / "f.png", dpi=60)
    table = aggregate_table(res)
    md = table.to_markdown()
    assert list(table.formatted.columns)[-3:] == ["P(> MC)", "P(> PPO)", "P(> GRU-PPO)"]
    gru = table.raw[(table.raw["group"] == "all") & (table.raw["algo"] == "gru_ppo")].iloc[0]
    assert gru["iqm"] == pytest.approx(rly.aggregate_iqm(MATRICES["gru_ppo"]))
    assert gru["p_gt_ppo"] == pytest.approx(rly.probability_of_improvement(MATRICES["gru_ppo"], MATRICES["ppo"]))
    assert f"{100 * gru['iqm']:.0f} [" in md


def test_report_builds_figure_5_and_the_aggregate_table(monkeypatch):
    """Wired into the report: the yardsticks come from eval_day_references (stubbed here)."""
    import nutribench.report.build as build

    ev = episodes_frame(seed=1)
    refs = ev[["regime", "seed", "episode"]].drop_duplicates().assign(never=-21.5, planner=-5.0)
    monkeypatch.setattr(build, "eval_day_references", lambda ev, log=None: refs)
    data = build.prepare(ev)
    fig = build.build_figure(5, data)
    table = build.build_table("aggregate", data)
    assert set(table.raw["algo"]) == {"ppo", "gru_ppo"}
    row = table.raw[(table.raw["group"] == "all") & (table.raw["algo"] == "ppo")].iloc[0]
    runs = ev[ev["algo"] == "ppo"].groupby(["regime", "seed"])["return"].mean().unstack("regime")
    assert row["mean"] == pytest.approx(rly.aggregate_mean(((runs + 21.5) / 16.5).to_numpy()))
    assert fig.data["point"].notna().all()
    assert build.FIGURES[5] == "fig5_aggregate" and build.TABLES["aggregate"] == "table_aggregate"


# --------------------------------------------------------------------------- paired comparison
def episodes_frame(regimes=("run0", "run3"), algos=("ppo", "gru_ppo"), seeds=(0, 1, 2), days=4, seed=0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    rows = []
    job = 0
    for r in regimes:
        for a in algos:
            for s in seeds:
                job += 1
                for e in range(days):
                    rows.append(
                        {
                            "regime": r,
                            "regime_version": 2,
                            "algo": a,
                            "algo_version": 1,
                            "seed": s,
                            "budget": 100,
                            "phase": "eval",
                            "episode": e,
                            "return": float(rng.normal(-15, 5)),
                            "job_id": job,
                        }
                    )
    return pd.DataFrame(rows)


def test_paired_difference_equals_a_hand_computation():
    # run1: seeds 0 and 1, two days each; run2: seed 0, one day (B ties A there)
    rows = [
        ("run1", 0, 0, -10.0, -14.0),
        ("run1", 0, 1, -12.0, -11.0),
        ("run1", 1, 0, -9.0, -15.0),
        ("run1", 1, 1, -8.0, -16.0),
        ("run2", 0, 0, -20.0, -20.0),
    ]
    ev = pd.DataFrame(
        [
            {"regime": r, "seed": s, "episode": e, "phase": "eval", "algo": a, "return": v}
            for r, s, e, va, vb in rows
            for a, v in (("gru_ppo", va), ("ppo", vb))
        ]
    )
    c = compare_agents(ev, "gru_ppo", "ppo", reps=20_000)
    rows_ = c.rows.set_index("regime")
    # run1: differences +4, -1 (seed 0), +6, +8 (seed 1): mean 17/4; A higher on 3 of 4 days
    assert rows_.loc["run1", "diff"] == pytest.approx(17 / 4)
    assert rows_.loc["run1", "p_a_better"] == pytest.approx(3 / 4)
    assert rows_.loc["run1", "seeds"] == 2 and rows_.loc["run1", "days"] == 4
    assert rows_.loc["run1", "a_mean"] == pytest.approx(-39 / 4) and rows_.loc["run1", "b_mean"] == pytest.approx(
        -56 / 4
    )
    # a seed's days count as one value: seed 0's mean difference 1.5, seed 1's 7; Student's t
    # over those two (1 degree of freedom, standard error 2.75), by hand
    half = 12.706204736174707 * 2.75
    assert rows_.loc["run1", "diff_lo"] == pytest.approx(4.25 - half) and rows_.loc["run1", "diff_hi"] == pytest.approx(
        4.25 + half
    )
    # run2: one seed, a tie: P = 1/2, no interval
    assert rows_.loc["run2", "diff"] == 0 and rows_.loc["run2", "p_a_better"] == 0.5
    assert np.isnan(rows_.loc["run2", "diff_lo"])
    # over both regimes: 5 paired days pooled, 3 seeds
    assert rows_.loc["all", "diff"] == pytest.approx(17 / 5)
    assert rows_.loc["all", "p_a_better"] == pytest.approx(3.5 / 5)
    assert rows_.loc["all", "seeds"] == 3 and rows_.loc["all", "days"] == 5
    assert "+4.25 [-30.69, +39.19]" in c.to_text() and "| run1 | 2 | 4 |" in c.to_markdown()


def test_pairing_is_by_seed_and_day_not_by_row_order():
    """A scores exactly B + 1 on every day; B's returns differ from day to day. Shuffle the
    rows and give A its days in another order: the difference stays exactly 1 and A wins
    every day. Pairing by position (or by seed alone) would not."""
    b = episodes_frame(algos=("ppo",), seeds=(0, 1, 2, 3), days=5)
    a = b.assign(algo="gru_ppo", job_id=b["job_id"] + 100, **{"return": b["return"] + 1.0})
    a = a.sort_values(["regime", "seed", "episode"], ascending=[True, False, False])  # another day order
    ev = pd.concat([b, a]).sample(frac=1, random_state=7).reset_index(drop=True)
    c = compare_agents(ev, "gru_ppo", "ppo", reps=2000)
    assert c.rows["diff"].to_numpy() == pytest.approx(1.0)
    assert (c.rows["p_a_better"] == 1.0).all()
    assert c.rows["diff_lo"].to_numpy() == pytest.approx(1.0) and c.rows["diff_hi"].to_numpy() == pytest.approx(1.0)
    assert set(c.rows["regime"]) == {"run0", "run3", "all"}
    days = paired_days(ev, "gru_ppo", "ppo")
    assert (days["a"] - days["b"]).to_numpy() == pytest.approx(1.0) and len(days) == 2 * 4 * 5
    # the test can fail: the same rows paired by position within a (regime, seed) are not A = B + 1
    by_position = np.concatenate(
        [
            ev[(ev.algo == "gru_ppo") & (ev.regime == r) & (ev.seed == s)]["return"].to_numpy()
            - ev[(ev.algo == "ppo") & (ev.regime == r) & (ev.seed == s)]["return"].to_numpy()
            for r in ("run0", "run3")
            for s in range(4)
        ]
    )
    assert not np.allclose(by_position, 1.0)


def test_only_common_seeds_and_days_are_paired():
    ev = episodes_frame(regimes=("run3",), algos=("ppo",), seeds=(0, 1, 2), days=5)
    other = episodes_frame(regimes=("run3",), algos=("gru_ppo",), seeds=(1, 2, 3), days=3, seed=1)
    c = compare_agents(pd.concat([ev, other]), "gru_ppo", "ppo", reps=500)
    assert c.rows.iloc[0]["seeds"] == 2 and c.rows.iloc[0]["days"] == 6  # seeds 1, 2 x days 0-2
    assert sorted(c.days["seed"].unique()) == [1, 2] and sorted(c.days["episode"].unique()) == [0, 1, 2]
    assert any("seeds 3 of gru_ppo have no partner" in n for n in c.notes)
    assert any("seeds 0 of ppo have no partner" in n for n in c.notes)


def test_compare_errors_in_the_library():
    ev = episodes_frame()
    with pytest.raises(CompareError, match="two different"):
        compare_agents(ev, "ppo", "ppo")
    with pytest.raises(CompareError, match="sac: no evaluation days"):
        compare_agents(ev, "sac", "ppo")
    disjoint = pd.concat([ev[(ev.algo == "ppo") & (ev.seed == 0)], ev[(ev.algo == "gru_ppo") & (ev.seed == 1)]])
    with pytest.raises(CompareError, match="share no seed"):
        compare_agents(disjoint, "gru_ppo", "ppo")
    with pytest.raises(CompareError, match="--regimes run5"):
        compare_agents(ev, "gru_ppo", "ppo", regimes=["run5"])
    with pytest.raises(ValueError, match="several rows"):
        compare_agents(pd.concat([ev, ev]), "gru_ppo", "ppo")


# --------------------------------------------------------------------------- the command
@pytest.fixture(scope="module")
def db(tmp_path_factory) -> Path:
    from tests.test_report_cli import make_db

    return make_db(
        tmp_path_factory.mktemp("cmp") / "cmp.db",
        regimes=("run0", "run3"),
        algos=("ppo", "gru_ppo", "sac"),
        seeds=(0, 1),
        eval_eps=3,
        steps=False,
    )


def compare(*args: str):
    return runner.invoke(app, ["compare", *args])


def test_compare_command_prints_the_library_rows(db: Path):
    from nutribench.report.compare import load_comparison

    result = compare("gru_ppo", "ppo", "--db", str(db), "--reps", "500")
    assert result.exit_code == 0, result.output
    c = load_comparison(db, "gru_ppo", "ppo", reps=500)
    ev = pd.read_sql("select * from episode_metrics where phase = 'eval'", f"sqlite:///{db}")
    run3 = ev[ev.regime == "run3"].pivot_table(index=["seed", "episode"], columns="algo", values="return")
    row = c.rows.set_index("regime").loc["run3"]
    assert row["diff"] == pytest.approx((run3["gru_ppo"] - run3["ppo"]).mean())
    assert row["seeds"] == 2 and row["days"] == 6
    assert f"{row['diff']:+.2f} [" in result.output and "all (run0, run3)" in result.output
    md = compare("gru_ppo", "ppo", "--db", str(db), "--reps", "500", "--markdown", "--regimes", "run3")
    assert md.exit_code == 0 and "| run3 | 2 | 6 |" in md.output and "all (" not in md.output


@pytest.mark.parametrize(
    "args, message",
    [
        (["gru_ppo", "nope"], "nope: no evaluation days in the database, which has them for ppo, sac, gru_ppo"),
        (["ppo", "ppo"], "give two different agent configs"),
        (["gru_ppo", "ppo", "--regimes", "run9"], "--regimes run9: gru_ppo and ppo were not both evaluated there"),
        (["gru_ppo", "ppo", "--regimes", ","], "--regimes: give a comma list"),
    ],
)
def test_compare_one_line_errors(db: Path, args, message):
    assert message in one_error_line(compare(*args, "--db", str(db)))


def test_compare_no_common_seed_and_no_database(tmp_path: Path):
    from tests.test_report_cli import make_db

    a = make_db(tmp_path / "a.db", regimes=("run3",), algos=("ppo", "gru_ppo"), seeds=(0,), eval_eps=2, steps=False)
    with sqlite3.connect(a) as con:  # gru_ppo's job ran with another seed
        con.execute(
            "UPDATE jobs SET seed = 5 WHERE agent_config_id = (SELECT id FROM agent_configs WHERE name = 'gru_ppo')"
        )
    line = one_error_line(compare("gru_ppo", "ppo", "--db", str(a)))
    assert "share no seed on run3" in line and "gru_ppo: seeds 5" in line and "ppo: seeds 0" in line
    assert "no results database" in one_error_line(compare("gru_ppo", "ppo", "--db", str(tmp_path / "nope.db")))


# --------------------------------------------------------------------------- rliable's own bootstrap
def test_intervals_match_rliable_library_where_it_imports():
    """rliable.library needs arch < 8, which fails at import under pandas 3 (the reason for
    our own bootstrap); where it does import (pandas 2), our intervals are rliable's up to
    Monte Carlo noise. CI runs this test a second time in an environment where it imports
    (``.ci/run``: pandas 2 ahead of the project's packages; arch 7 comes with rliable), with
    ``NUTRIBENCH_RLIABLE_ORACLE=1``: there a failed import fails the test."""
    try:
        from rliable import library as rl
    except Exception as e:  # noqa: BLE001 - arch's TypeError under pandas 3
        why = f"rliable.library does not import here ({type(e).__name__}): the pandas-3 trap"
        if os.environ.get("NUTRIBENCH_RLIABLE_ORACLE"):
            pytest.fail(f"{why}; NUTRIBENCH_RLIABLE_ORACLE is set, so it must")
        pytest.skip(f"{why} (CI runs it where it imports: .ci/run)")
    from nutribench.stats import percentile_interval

    ss = score_set(scores_frame(), REGIMES)
    ours = interval_estimates(ss).set_index(["algo", "aggregate"])
    funcs = {
        "iqm": rly.aggregate_iqm,
        "median": rly.aggregate_median,
        "mean": rly.aggregate_mean,
        "optimality_gap": rly.aggregate_optimality_gap,
    }
    np.random.seed(0)
    for agg, f in funcs.items():
        points, cis = rl.get_interval_estimates(MATRICES, lambda m, f=f: np.array([f(m)]), reps=20_000)
        for algo in MATRICES:
            # the tables print intervals made without resamples now; the module's stratified
            # percentile bootstrap (what they printed before) is still rliable's
            resampled = stratified_resamples(ss.runs[algo], 20_000, np.random.default_rng(0))
            lo, hi = percentile_interval(BATCHED[agg](resampled))
            width = cis[algo][1, 0] - cis[algo][0, 0]
            assert ours.loc[(algo, agg), "point"] == pytest.approx(points[algo][0])
            assert lo == pytest.approx(cis[algo][0, 0], abs=0.05 * width + 1e-9)
            assert hi == pytest.approx(cis[algo][1, 0], abs=0.05 * width + 1e-9)


# --------------------------------------------------------------------------- one module draws resamples
_DRAWS = {"integers", "choice", "randint", "permutation", "random_integers"}
_RESAMPLING = re.compile(r"bootstrap|resampl|\breps\b", re.IGNORECASE)


def resampling_functions(source: str) -> list[str]:
    """The functions of ``source`` that draw random indices or values (``rng.integers``,
    ``.choice``, ``np.random.randint``, ...) and speak of a bootstrap, resamples or ``reps``
    in their name, docstring or body: a bootstrap drawn there."""
    tree = ast.parse(source)
    found = []
    for fn in ast.walk(tree):
        if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
            continue
        draws = [
            n
            for n in ast.walk(fn)
            if isinstance(n, ast.Call) and isinstance(n.func, ast.Attribute) and n.func.attr in _DRAWS
        ]
        text = ast.get_source_segment(source, fn) or ""
        if draws and _RESAMPLING.search(text):
            found.append(getattr(fn, "name", "<lambda>"))
    return found


def test_the_scan_finds_a_bootstrap_drawn_outside_the_statistics_module():
    """The scan below would fail on the code before the statistics module: compare's own loop."""
    old = """
def _summary(per, reps, seed):
    rng = np.random.default_rng(seed)
    for p in per:
        pick = rng.integers(0, len(p), size=(reps, len(p)))
"""
    assert resampling_functions(old) == ["_summary"]
    vectorised = "def f(x, reps):\n    return x[np.random.default_rng(0).choice(len(x), (reps, len(x)))]\n"
    assert resampling_functions(vectorised) == ["f"]
    assert resampling_functions("def days(rng, n):\n    return rng.integers(0, n, size=5)\n") == []


def test_only_the_statistics_module_draws_bootstrap_resamples():
    import nutribench

    package = Path(nutribench.__file__).parent
    drawn = {
        str(p.relative_to(package.parent)): found
        for p in sorted(package.rglob("*.py"))
        if p != package / "stats.py" and (found := resampling_functions(p.read_text()))
    }
    assert drawn == {}
    assert resampling_functions((package / "stats.py").read_text())  # and it does draw them


# --------------------------------------------------------------------------- the intervals
def test_the_chosen_intervals_equal_scipys():
    """The mean's interval is Student's t; the IQM's Tukey-McLaughlin's trimmed t, which scipy
    computes (``mstats.trimmed_mean_ci``) where a quarter of the values is a whole number."""
    from scipy import stats as sps
    from scipy.stats import mstats

    from nutribench.stats import CHOSEN, iqm_runs_ci, mean_ci

    assert CHOSEN == {"mean": "t", "iqm": "t", "paired": "t"}
    rng = np.random.default_rng(3)
    x = rng.normal(size=5)
    lo, hi = sps.t.interval(0.95, 4, loc=x.mean(), scale=sps.sem(x))
    assert mean_ci(x) == pytest.approx((x.mean(), lo, hi))
    for n in (8, 12, 20):
        x = rng.normal(size=n)
        point, lo, hi = iqm_runs_ci([x])
        assert point == pytest.approx(rly.aggregate_iqm(x[:, None]))
        assert (lo, hi) == pytest.approx(tuple(mstats.trimmed_mean_ci(x, limits=(0.25, 0.25))))
    # two regimes far apart: the standard error is within regimes, not the spread between them
    a, b = rng.normal(size=8), rng.normal(size=8) + 100
    point, lo, hi = iqm_runs_ci([a, b])
    assert point == pytest.approx(rly.aggregate_iqm(np.stack([a, b], axis=1)))
    assert hi - lo < 3 and lo < point < hi


def test_the_aggregates_intervals_are_computed_not_drawn():
    """The aggregate table's median, mean and optimality gap, the profiles' bands and P(X > Y):
    t intervals with standard errors within regimes (against scipy and hand computations), the
    median's the quantiles of the median of t-distributed regime means (against a Monte Carlo
    of that model), P(X > Y)'s from DeLong's variance; the table's rows are these."""
    from scipy import stats as sps

    from nutribench.stats import improvement_ci, median_of_means_ci, strata_t

    rng = np.random.default_rng(5)
    x = rng.normal(size=6)
    assert np.ravel(strata_t(x, [6])) == pytest.approx(
        [x.mean(), *sps.t.interval(0.95, 5, loc=x.mean(), scale=sps.sem(x))]
    )
    a, b = rng.normal(size=5), rng.normal(size=8) + 3
    va, vb = a.var(ddof=1) / 5 / 4, b.var(ddof=1) / 8 / 4  # each regime weighs 1/2
    df = (va + vb) ** 2 / (va**2 / 4 + vb**2 / 7)
    half = sps.t.ppf(0.975, df) * np.sqrt(va + vb)
    mid = (a.mean() + b.mean()) / 2
    assert np.ravel(strata_t(np.concatenate([a, b]), [5, 8], "regime")) == pytest.approx([mid, mid - half, mid + half])
    for regimes in (5, 6):  # odd: an order statistic; even: the mean of the two middle ones
        runs = [rng.normal(0.3 * i, 1, 5) for i in range(regimes)]
        point, lo, hi = median_of_means_ci(runs)
        means = np.array([r.mean() for r in runs])
        ses = np.array([sps.sem(r) for r in runs])
        model = np.median(means + ses * rng.standard_t(4, size=(400_000, regimes)), axis=1)
        assert point == pytest.approx(np.median(means))
        assert (lo, hi) == pytest.approx(tuple(np.percentile(model, [2.5, 97.5])), abs=0.01)
    assert median_of_means_ci([np.full(5, float(k)) for k in range(4)]) == (1.5, 1.5, 1.5)  # no spread
    # DeLong: the placements' variances over each side
    xs, ys = rng.normal(1, 1, 6), rng.normal(0, 1, 5)
    psi = (xs[:, None] > ys[None, :]).astype(float)
    var = psi.mean(axis=1).var(ddof=1) / 6 + psi.mean(axis=0).var(ddof=1) / 5
    p, lo, hi = improvement_ci([xs], [ys])
    assert p == pytest.approx(psi.mean())
    assert (lo, hi) == pytest.approx(
        (max(p - sps.t.ppf(0.975, 9) * np.sqrt(var), 0), min(p + sps.t.ppf(0.975, 9) * np.sqrt(var), 1))
    )
    ss = score_set(scores_frame(), REGIMES)
    iv = interval_estimates(ss).set_index(["algo", "aggregate"])
    runs = ss.runs["ppo"]
    assert tuple(iv.loc[("ppo", "median"), ["point", "lo", "hi"]]) == pytest.approx(median_of_means_ci(runs))
    pooled = np.concatenate(runs)
    mean = [float(v[0]) for v in strata_t(pooled, [5] * 4, "regime")]
    assert tuple(iv.loc[("ppo", "mean"), ["point", "lo", "hi"]]) == pytest.approx(mean)
    capped = [float(v[0]) for v in strata_t(np.minimum(pooled, 1.0), [5] * 4, "run")]
    assert tuple(iv.loc[("ppo", "optimality_gap"), ["lo", "hi"]]) == pytest.approx((1 - capped[2], 1 - capped[1]))
    imp = improvement_probabilities(ss).set_index(["x", "y"])
    assert tuple(imp.loc[("mc", "ppo"), ["p", "lo", "hi"]]) == pytest.approx(improvement_ci(ss.runs["mc"], runs))


def test_a_small_bootstrap_enumerates_every_resample():
    """At 5 seeds the 3,125 ordered resamples are 126 multisets; their weighted percentile
    interval is that of all 3,125 resamples, brute force."""
    import itertools

    from nutribench.stats import design, percentile_interval, weighted_quantiles

    d = design(5)
    assert d.exact and d.idx.shape == (126, 5) and d.weights.sum() == pytest.approx(1)
    x = np.array([-5.9, 6.5, 4.0, 41.9, 13.9])
    every = np.array([x[list(i)].mean() for i in itertools.product(range(5), repeat=5)])
    assert percentile_interval(x[d.idx].mean(axis=1), 0.95, d.weights) == pytest.approx(
        tuple(weighted_quantiles(every[None, :], np.full(every.size, 1 / every.size), np.array([[0.025, 0.975]]))[0])
    )
    assert design(10).idx.shape == (92378, 10) and not design(11, reps=100).exact


def test_no_printed_digit_moves_with_the_bootstraps_seed():
    """The printed intervals of a mean, an IQM and a paired difference over seeds, and every
    interval of the aggregate table (median, mean, optimality gap, P(X > Y)) and the profiles'
    bands, are the same to the last printed digit under any bootstrap seed; the control below
    shows that a drawn percentile bootstrap (2,000 resamples, as before) moves them."""
    from nutribench.stats import percentile_interval, stratified_resamples

    ev = episodes_frame(seeds=(0, 1, 2, 3, 4), days=5)
    texts = {s: compare_agents(ev, "gru_ppo", "ppo", reps=2000, seed=s).to_text() for s in (0, 1, 2)}
    assert texts[0] == texts[1] == texts[2]
    results = {s: aggregate_scores(scores_frame(), reps=2000, seed=s) for s in (0, 1, 2)}
    tables = {s: aggregate_table(r).formatted for s, r in results.items()}
    # every column of the aggregate table: IQM, median, mean, optimality gap, P(> Y)
    assert all(tables[s].equals(tables[0]) for s in (1, 2))
    assert tables[0].map(lambda v: "[" in str(v)).sum().sum() >= 3 * 7  # intervals printed, not "n/a"
    for s in (1, 2):  # and the profiles' bands, to the digit
        assert results[s].profiles[["lo", "hi"]].round(4).equals(results[0].profiles[["lo", "hi"]].round(4))
    # control: the drawn bootstrap of the same IQMs does move a printed digit with its seed
    runs = [MATRICES["ppo"][:, j] for j in range(4)]
    drawn = {
        s: "{:.3f} {:.3f}".format(
            *percentile_interval(
                np.concatenate(stratified_resamples(runs, 2000, np.random.default_rng(s)), axis=1).mean(axis=1)
            )
        )
        for s in (0, 1, 2)
    }
    assert len(set(drawn.values())) > 1


@pytest.mark.slow
def test_the_coverage_simulation_chose_what_the_statistics_module_says():
    """``benchmarks/coverage.py`` (its first table, about 100 s of CPU) reproduces
    :data:`nutribench.stats.CHOSEN` and :data:`~nutribench.stats.COVERAGE`."""
    import importlib.util

    from nutribench.stats import CHOSEN, COVERAGE

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "coverage.py"
    spec = importlib.util.spec_from_file_location("coverage_simulation", path)
    sim = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sim)
    chosen = sim.choose(sim.run())
    assert {k: v[0] for k, v in chosen.items()} == {**CHOSEN, "iqm x3": CHOSEN["iqm"]}
    for label, statistic in (("mean", "mean"), ("paired", "paired")):
        assert chosen[label][1] == pytest.approx(COVERAGE[statistic], abs=5e-4)
    worst = {n: min(chosen["iqm"][1][n], chosen["iqm x3"][1][n]) for n in (5, 10)}
    assert worst == pytest.approx(COVERAGE["iqm"], abs=5e-4)


@pytest.mark.slow
def test_the_coverage_simulation_measured_what_the_aggregates_captions_quote():
    """The second table of ``benchmarks/coverage.py`` (about 4 minutes of CPU) reproduces
    :data:`nutribench.stats.AGGREGATE_COVERAGE` to the digit the captions print (a coverage
    is a count of 2,000 datasets, so 94.85 % and 94.8 % print alike)."""
    import importlib.util

    from nutribench.stats import AGGREGATE_COVERAGE

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "coverage.py"
    spec = importlib.util.spec_from_file_location("coverage_simulation", path)
    sim = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(sim)
    measured = sim.aggregate_coverage(sim.run_aggregates())
    assert measured.keys() == AGGREGATE_COVERAGE.keys()
    for name, cov in AGGREGATE_COVERAGE.items():
        printed = {n: f"{100 * v:.1f}" for n, v in cov.items()}
        assert {n: f"{100 * v:.1f}" for n, v in measured[name].items()} == printed, name


def test_total_cost_weighs_each_block_by_its_length():
    """Two short blocks 10 % faster without, one long block equal: the share of the total time
    is 0.2 / 12, where the median of the blocks' ratios (paired_cost) would say 10 %."""
    import importlib.util

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "cost_stats.py"  # developer code
    spec = importlib.util.spec_from_file_location("cost_stats", path)
    cost_stats = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(cost_stats)
    paired_cost, total_cost = cost_stats.paired_cost, cost_stats.total_cost

    cost, lo, hi = total_cost([1.0, 1.0, 10.0], [0.9, 0.9, 10.0])
    assert cost == pytest.approx(0.2 / 12) and lo <= cost <= hi
    assert paired_cost([1.0, 1.0, 10.0], [0.9, 0.9, 10.0])[0] == pytest.approx(0.1)


def test_welch_t_of_two_samples_equals_scipys_welch_interval():
    """A difference of two independent means by welch_t/contrast_ci is Welch's t interval, as
    scipy's ttest_ind(equal_var=False) computes it; one regime alone is mean_ci's t interval."""
    from scipy.stats import ttest_ind

    from nutribench.stats import contrast_ci, mean_ci

    a = np.array([0.31, 0.52, 0.12, 0.44, 0.95])
    b = np.array([0.05, -0.20, 0.33, 0.10, -0.41, 0.02, 0.15])
    ci = ttest_ind(a, b, equal_var=False).confidence_interval(0.95)
    point, lo, hi = contrast_ci([a, b], [1.0, -1.0])
    assert point == pytest.approx(a.mean() - b.mean(), abs=1e-12)
    assert (lo, hi) == pytest.approx((ci.low, ci.high), abs=1e-9)
    assert contrast_ci([a], [1.0]) == pytest.approx(mean_ci(a), abs=1e-12)


def test_a_contrast_of_one_run_regimes_has_no_interval():
    from nutribench.stats import contrast_ci

    point, lo, hi = contrast_ci([np.array([0.4]), np.array([0.1])], [1.0, -1.0])
    assert point == pytest.approx(0.3) and np.isnan(lo) and np.isnan(hi)
