"""The lookahead and clairvoyant references beside the agents (issue 73): the test days'
returns committed in regimes/references.csv (they replay, they are ordered, a stale file is
not used), and their shares in the results table, Figure 3, Figure 5 and the leaderboard."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from nutribench.agents.days import eval_food_streams
from nutribench.baselines import (
    REFERENCE_COLUMNS,
    TEST_DAY_SAMPLES,
    play_simple_policy,
    play_strong_policy,
    test_day_references,
)
from nutribench.config import list_regimes, load_env_config, regimes_dir
from nutribench.scheduler.grid import PRESETS

test_day_references.__test__ = False  # a library function named test_*, not a test


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
    t = table_results(df, references=refs)
    assert t.raw["lookahead_gap"].to_numpy() == pytest.approx(1.1)
    assert t.raw["clairvoyant_gap"].to_numpy() == pytest.approx(1.15)
    assert set(t.formatted["lookahead / clairvoyant"]) == {"110 % / 115 %"}
    assert "100 % is the greedy planner, not the optimum" in t.title
    # a day the committed file lacks: no share rather than one of other days
    gap = refs.copy()
    gap.loc[gap.index[0], "lookahead"] = np.nan
    t = table_results(df, references=gap)
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
    from nutribench.report.leaderboard import REFERENCE_PROTOCOL, leaderboard_rows, leaderboard_table
    from nutribench.report.references import aggregate_points

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


# --------------------------------------------------------------------------- regimes/references.csv
@pytest.fixture(scope="module")
def committed() -> pd.DataFrame:
    return pd.read_csv(regimes_dir() / "references.csv")


def test_the_committed_references_cover_every_regime_and_test_day(committed):
    assert list(committed.columns) == list(REFERENCE_COLUMNS)
    seeds = PRESETS["paper"].seeds
    for regime in list_regimes():
        cfg = load_env_config(regime)
        rows = committed[committed["regime"] == regime]
        assert set(rows["sha256"]) == {cfg.sha256}, f"{regime}: regimes/references.csv is stale"
        assert sorted(zip(rows["seed"], rows["episode"])) == sorted((s, e) for s in seeds for e in range(5))


@pytest.mark.parametrize("regime", list_regimes())
def test_on_the_test_days_clairvoyant_lookahead_planner_are_ordered(committed, regime):
    """Per regime, over the test days: clairvoyant >= lookahead >= planner (means); on a day
    whose clairvoyant search is exact, the clairvoyant's return is at least every other
    policy's (the simple ones played here afresh, the lookahead's from the file)."""
    rows = committed[committed["regime"] == regime].sort_values(["seed", "episode"])
    mean = rows[["planner", "lookahead", "clairvoyant"]].mean()
    assert mean["clairvoyant"] >= mean["lookahead"] >= mean["planner"]
    for seed, days in rows.groupby("seed"):
        foods = eval_food_streams(regime, int(seed), 5)
        for policy in ("never", "random", "always", "planner"):
            played = np.array([r["return"] for r in play_simple_policy(policy, regime, foods)])
            if policy in ("never", "planner"):
                assert played == pytest.approx(days[policy].to_numpy(), abs=1e-9)
            exact = (days["search"] == "exact").to_numpy()
            assert np.all(days["clairvoyant"].to_numpy()[exact] >= played[exact] - 1e-9)
        exact = days["search"] == "exact"
        assert (days["clairvoyant"][exact] >= days["lookahead"][exact] - 1e-9).all()


@pytest.mark.parametrize("regime", ["run0", "run6"])
def test_the_committed_references_replay(committed, regime):
    """The file's first two days of seed 0 played again (lookahead at its 256 futures)."""
    cfg = load_env_config(regime)
    foods = eval_food_streams(cfg, 0, 2)
    rows = committed[(committed["regime"] == regime) & (committed["seed"] == 0)].sort_values("episode").head(2)
    look = play_strong_policy("lookahead", cfg, foods, samples=TEST_DAY_SAMPLES, seed=0)
    clair = play_strong_policy("clairvoyant", cfg, foods)
    assert [r["return"] for r in look] == pytest.approx(rows["lookahead"].to_list(), abs=1e-9)
    assert [r["return"] for r in clair] == pytest.approx(rows["clairvoyant"].to_list(), abs=1e-9)
    assert [r["search"] for r in clair] == rows["search"].to_list()


@pytest.mark.slow
def test_a_regime_of_committed_references_is_remade_exactly(committed):
    rows = pd.DataFrame(test_day_references("run3", PRESETS["paper"].seeds), columns=list(REFERENCE_COLUMNS))
    want = committed[committed["regime"] == "run3"].reset_index(drop=True)
    pd.testing.assert_frame_equal(rows, want, check_exact=False, atol=1e-9, rtol=0)


def test_committed_references_of_a_changed_regime_file_are_not_used(monkeypatch, tmp_path):
    import shutil

    from nutribench.report.references import committed_references

    for f in regimes_dir().iterdir():
        if f.is_file():
            shutil.copy(f, tmp_path / f.name)
    run3 = tmp_path / "run3.toml"
    run3.write_text(run3.read_text().replace("seed = 1003", "seed = 1004"))
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(tmp_path))
    logged: list[str] = []
    rows = committed_references(logged.append)
    assert "run3" not in set(rows["regime"]) and "run0" in set(rows["regime"])
    assert any("run3" in line and "another regime file" in line for line in logged)
