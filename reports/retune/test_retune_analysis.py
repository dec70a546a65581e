"""reports/retune/analyse.py on synthetic run scores: R1's spread and rank, R2's pairing by seed,
R3's enumerated bootstrap against brute force, and a partial grid ("not yet run", no error)."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from report_scripts import load_script

from nutribench.stats import iqm_runs_ci, mean_ci, percentile_interval


@pytest.fixture(scope="module")
def analyse():
    return load_script("retune", "analyse")


def frame(analyse, level: dict[str, float], files=None, regimes=None, seeds=None, noise: float = 0.1, seed: int = 0):
    """Scores per (file, regime, seed): the file's level plus a seed effect shared by every file
    (so pairs by seed differ by less than their levels vary) plus a little noise."""
    rng = np.random.default_rng(seed)
    seeds = analyse.SEEDS if seeds is None else seeds
    effect = {s: float(rng.normal(0, 0.3)) for s in analyse.SEEDS}
    rows = [
        {"regime": r, "algo": f, "seed": s, "score": level[f] + effect[s] + float(rng.normal(0, noise))}
        for f in (files or level)
        for r in regimes or analyse.REGIMES
        for s in seeds
    ]
    return pd.DataFrame(rows)


ALL = {
    "ppo_tuned_v2": 0.55,
    "ppo_tuned_v2b": 0.30,
    "ppo_tuned_v2c": 0.62,
    "gru_ppo_tuned_v2": 0.80,
    "gru_ppo_tuned_v2b": 0.70,
    "gru_ppo_tuned_v2c": 0.75,
    "mc_tuned_v2": 0.2,
    "ddqn_tuned_v2": 0.1,
}


def test_r1_spread_is_max_minus_min_of_the_iqms_and_rank_counts_the_higher_ones(analyse):
    scores = frame(analyse, ALL)
    cs = analyse.cells(scores)
    files = analyse.FILES["PPO"]
    spread, rank = analyse.spread_and_rank(cs, files, "run3")
    iqms = [iqm_runs_ci([scores[(scores.algo == f) & (scores.regime == "run3")]["score"].to_numpy()])[0] for f in files]
    assert spread == pytest.approx(max(iqms) - min(iqms), abs=1e-12) and spread > 0.2
    assert rank == 1 + sum(x > iqms[0] for x in iqms[1:])
    # the levels make B lowest and C highest, A second: rank 2 unless noise turned it
    assert rank == 2
    # A raised above both: first
    up = scores.copy()
    up.loc[up.algo == "ppo_tuned_v2", "score"] += 1.0
    assert analyse.spread_and_rank(analyse.cells(up), files, "run3")[1] == 1


def test_r1_needs_every_seed_of_every_file(analyse):
    scores = frame(analyse, ALL)
    one_fewer = scores[~((scores.algo == "ppo_tuned_v2b") & (scores.regime == "run1") & (scores.seed == 5004))]
    cs = analyse.cells(one_fewer)
    assert analyse.spread_and_rank(cs, analyse.FILES["PPO"], "run1") is None
    assert analyse.spread_and_rank(cs, analyse.FILES["PPO"], "run3") is not None
    assert analyse.level_text(cs["ppo_tuned_v2b", "run1"]).endswith("(9 of 10 seeds)")


def test_r2_pairs_each_gru_ppo_run_with_the_ppo_run_of_its_seed(analyse):
    # GRU-PPO's run = PPO's run of the same seed + 0.25 exactly: paired by seed, every difference
    # is 0.25 (a zero-width interval), while the runs themselves vary by tenths from seed to seed
    ppo = frame(analyse, {"ppo_tuned_v2": 0.4}, noise=0.2, seed=5)
    gru = ppo.assign(algo="gru_ppo_tuned_v2", score=ppo["score"] + 0.25)
    both = pd.concat([ppo, gru]).sample(frac=1.0, random_state=1)  # rows in no order
    cs = analyse.cells(both)
    for regs in [("run1",), analyse.REGIMES]:
        d = analyse.paired(cs, "gru_ppo_tuned_v2", "ppo_tuned_v2", regs)
        assert len(d) == 10 and np.allclose(d.to_numpy(), 0.25)
        point, lo, hi = mean_ci(d.to_numpy())
        assert point == pytest.approx(0.25) and hi - lo < 1e-9
    assert np.ptp(cs["ppo_tuned_v2", "run1"].to_numpy()) > 0.3
    # pooled: per seed the mean over the regimes, the seeds kept apart
    shifted = both.copy()
    mask = (shifted.algo == "gru_ppo_tuned_v2") & (shifted.regime == "run6")
    shifted.loc[mask, "score"] += shifted.loc[mask, "seed"] - 5000  # seed s: +s - 5000 on run6 only
    d = analyse.paired(analyse.cells(shifted), "gru_ppo_tuned_v2", "ppo_tuned_v2", analyse.REGIMES)
    assert np.allclose(d.to_numpy(), 0.25 + (d.index.to_numpy() - 5000) / 3)
    # a seed one file lacks is left out, not paired with another seed
    gone = both[~((both.algo == "ppo_tuned_v2") & (both.seed == 5007) & (both.regime == "run3"))]
    d = analyse.paired(analyse.cells(gone), "gru_ppo_tuned_v2", "ppo_tuned_v2", ("run3",))
    assert 5007 not in d.index and len(d) == 9 and np.allclose(d.to_numpy(), 0.25)
    assert analyse.paired_text(d).endswith("(9 of 10 seeds)")


def brute_force(g: np.ndarray, p: np.ndarray, confidence: float = 0.95) -> tuple[float, float]:
    """R3's bootstrap by every ordered resample (each equally likely): GRU-PPO studies, PPO
    studies and seeds drawn with replacement; the statistic the mean over the resampled pairs of
    the mean over the resampled seeds of the difference."""
    n, kg, kp = g.shape[0], g.shape[1], p.shape[1]
    values = []
    for su in itertools.product(range(kg), repeat=kg):
        for sv in itertools.product(range(kp), repeat=kp):
            for ss in itertools.product(range(n), repeat=n):
                pairs = [g[list(ss), i] - p[list(ss), j] for i in su for j in sv]
                values.append(np.mean([x.mean() for x in pairs]))
    values = np.array(values)
    return percentile_interval(values, confidence, np.ones(values.size))


def test_r3_enumerated_bootstrap_equals_brute_force_on_a_tiny_case(analyse):
    rng = np.random.default_rng(7)
    for _ in range(3):
        g, p = rng.normal(0.6, 0.3, (3, 2)), rng.normal(0.4, 0.3, (3, 2))
        point, lo, hi, n = analyse.r3_interval(g, p)
        b_lo, b_hi = brute_force(g, p)
        assert n == 3 * 3 * 10  # multisets: 3 of 2 studies (each agent), 10 of 3 seeds
        assert (lo, hi) == pytest.approx((b_lo, b_hi), abs=1e-12)
        assert point == pytest.approx(np.mean([(g[:, i] - p[:, j]).mean() for i in range(2) for j in range(2)]))
        assert lo < point < hi
    # at other levels too (the weighted quantiles, not just the ends that happen to coincide)
    assert analyse.r3_interval(g, p, 0.5)[1:3] == pytest.approx(brute_force(g, p, 0.5), abs=1e-12)


def test_r3_at_full_size_weighs_every_resample(analyse):
    rng = np.random.default_rng(2)
    g, p = rng.normal(0.7, 0.3, (10, 3)), rng.normal(0.4, 0.3, (10, 3))
    point, lo, hi, n = analyse.r3_interval(g, p)
    assert n == 10 * 10 * 92_378
    assert lo < point < hi and point == pytest.approx(g.mean() - p.mean())
    # the same data as the page reads it: the pooled row from every cell complete
    scores = frame(analyse, ALL)
    page = analyse.markdown(scores)
    assert "| not yet run" not in page
    assert "| E2 | holds |" in page and "| E1 | holds |" in page
    assert "| E3 | holds |" in page  # A (0.55) below C (0.62) on PPO


def test_a_partial_grid_says_not_yet_run_and_reads_nothing(analyse):
    # only PPO's files, one of them on two regimes and seven seeds
    ppo = frame(analyse, {k: v for k, v in ALL.items() if k.startswith("ppo")})
    part = ppo[~((ppo.algo == "ppo_tuned_v2c") & ((ppo.regime == "run6") | (ppo.seed > 5006)))]
    page = analyse.markdown(part)
    assert "(7 of 10 seeds)" in page
    for e in ("E1", "E2", "E3"):
        assert f"| {e} | not yet run |" in page
    r3 = page.split("## R3")[1].split("## R4")[0]
    assert r3.count("not yet run") == 4  # three regimes and pooled
    assert "`gru_ppo_tuned_v2`" in page.split("not yet run:")[1].split("\n")[0]
    # nothing at all, or a non-finite score (no yardstick): no error either
    empty = analyse.markdown(pd.DataFrame(columns=["regime", "algo", "seed", "score"]))
    assert "Files present: none" in empty and "| E1 | not yet run |" in empty
    nan = part.assign(score=np.where(part.seed == 5000, np.nan, part.score))
    assert "(9 of 10 seeds)" in analyse.markdown(nan)


def test_the_command_reads_a_database_of_no_jobs(analyse, tmp_path, capsys):
    from nutribench.store import open_store

    db = str(tmp_path / "empty.db")
    with open_store(db, writer=True):  # the schema, no job
        pass
    out = tmp_path / "new" / "results.md"
    assert analyse.main([db, "--out", str(out)]) == 0
    assert "Files present: none" in out.read_text()
    assert analyse.main([str(tmp_path / "absent.db")]) == 2
