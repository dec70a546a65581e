"""Seed-level statistics: the aggregate scores against rliable, the stratified
bootstrap, the paired comparison against a hand computation, pairing by seed and day, and
``nutribench compare``'s one-line errors."""

from __future__ import annotations

import os
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
        np.testing.assert_array_equal(ss.matrix(algo), m)  # runs x regimes, seeds in order
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
    assert [len(x) for x in runs] == [5, 5, 5, 3] and not ss.rectangular("ppo")
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
    # the bootstrap draws whole seeds: the resampled means are seed 0's (1.5), both (4.25) or seed 1's (7)
    assert rows_.loc["run1", "diff_lo"] == pytest.approx(1.5) and rows_.loc["run1", "diff_hi"] == pytest.approx(7.0)
    # run2: one seed, a tie: P = 1/2, no interval
    assert rows_.loc["run2", "diff"] == 0 and rows_.loc["run2", "p_a_better"] == 0.5
    assert np.isnan(rows_.loc["run2", "diff_lo"])
    # over both regimes: 5 paired days pooled, 3 seeds
    assert rows_.loc["all", "diff"] == pytest.approx(17 / 5)
    assert rows_.loc["all", "p_a_better"] == pytest.approx(3.5 / 5)
    assert rows_.loc["all", "seeds"] == 3 and rows_.loc["all", "days"] == 5
    assert "+4.25 [+1.50, +7.00]" in c.to_text() and "| run1 | 2 | 4 |" in c.to_markdown()


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
    ss = score_set(scores_frame(), REGIMES)
    ours = interval_estimates(ss, reps=20_000).set_index(["algo", "aggregate"])
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
            width = cis[algo][1, 0] - cis[algo][0, 0]
            assert ours.loc[(algo, agg), "point"] == pytest.approx(points[algo][0])
            assert ours.loc[(algo, agg), "lo"] == pytest.approx(cis[algo][0, 0], abs=0.05 * width + 1e-9)
            assert ours.loc[(algo, agg), "hi"] == pytest.approx(cis[algo][1, 0], abs=0.05 * width + 1e-9)
