"""reports/tuned/analyse.py: the tuned grid's tables from the project's own statistics, each of
the plan's 38 comparisons computed where its agents are present and "not yet run" where not,
and one line for a bad path."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from report_scripts import load_script

SEEDS = (0, 21, 9, 2003, 1997)
NEVER, PLANNER = -20.0, -4.0


@pytest.fixture(scope="module")
def analyse():
    return load_script("tuned", "analyse")


def _grid(shares: dict[str, float]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """Evaluation days of each agent on run0-run6 x 5 seeds x 5 days whose share of the gap is
    about ``shares[agent]`` (run0: about 1.1 for every agent), and constant yardsticks."""
    rng = np.random.default_rng(0)
    rows = []
    for algo, share in shares.items():
        for regime in (f"run{i}" for i in range(7)):
            for seed in SEEDS:
                s = (1.1 if regime == "run0" else share) + rng.normal(0, 0.05)
                for day in range(5):
                    ret = NEVER + (s + rng.normal(0, 0.02)) * (PLANNER - NEVER)
                    rows.append(
                        dict(
                            regime=regime,
                            algo=algo,
                            seed=seed,
                            episode=day,
                            phase="eval",
                            budget=5000,
                            **{"return": ret},
                        )
                    )
    ev = pd.DataFrame(rows)
    refs = ev[["regime", "seed", "episode"]].drop_duplicates().assign(never=NEVER, planner=PLANNER)
    return ev, refs


def test_tables_reuse_the_project_statistics_and_say_what_is_not_yet_run(analyse):
    from nutribench.report.aggregate import interval_estimates, run_scores, score_set

    ev, refs = _grid(
        {"mc": 0.5, "ppo": -0.4, "gru_ppo": 0.6, "ppo_tuned": 0.5, "gru_ppo_tuned": 0.55, "mc_tuned_set1": 0.5}
    )
    scores = run_scores(ev, refs)
    shares = analyse.day_shares(ev, refs)
    # a day's share on its run's yardstick averages to the run's score
    runs = shares.groupby(["regime", "algo", "seed"])["return"].mean().rename("mean").reset_index()
    both = runs.merge(scores, on=["regime", "algo", "seed"])
    assert np.allclose(both["mean"], both["score"])

    rows = analyse.protocol_rows(scores).set_index(["tuned_agent", "regime"])
    iv = interval_estimates(score_set(scores, ["run3"], ["ppo"]))
    iqm = iv[iv["aggregate"] == "iqm"].iloc[0]
    got = rows.loc[("ppo_tuned", "run3")]
    assert (got["paper_iqm"], got["paper_lo"], got["paper_hi"]) == pytest.approx((iqm.point, iqm.lo, iqm.hi))
    assert got["tuned_vs_paper"] == "higher (intervals apart)"
    assert rows.loc[("ppo_tuned", "delayed (run1-run6)"), "tuned_runs"] == 30
    assert rows.loc[("ddqn_tuned", "run3"), "tuned_vs_paper"] == "not yet run: needs ddqn_tuned, ddqn"
    assert rows.loc[("mc_tuned_set1", "run0"), "role"].startswith("exploratory")

    q = analyse.question_rows(ev, shares, scores)
    pre = [r for r in q if r["pre_registered"]]
    assert len(pre) == 38 and {r["question"] for r in q if not r["pre_registered"]} == {3, 4}
    by = {r["comparison"]: r for r in pre}
    q1 = by["gru_ppo_tuned - ppo_tuned, delayed (run1-run6) pooled"]
    assert q1["estimate"].startswith("share ") and "P(A > B)" in q1["estimate"]
    assert by["ppo_tuned, run3: IQM share vs 0 (never)"]["reading"] == "above never"
    assert by["sac_tuned, run3: IQM share vs 0 (never)"]["estimate"] == "not yet run: needs sac_tuned"
    assert "tuned ahead" in by["ppo_tuned - ppo, held-out (run3, run5, run6), paired by seed and day"]["reading"]
    drop = by["PPO: drop under delay (run0 - mean of run1-run6), paper vs ppo_tuned"]
    assert drop["reading"] == "tuned drop smaller (intervals apart)"
    assert by["MC: drop under delay (run0 - mean of run1-run6), paper vs mc_tuned"]["estimate"].startswith(
        "not yet run: needs mc_tuned"
    )
    md = analyse.questions_markdown(q, ["ppo_tuned"], ["ddqn_tuned"], [])
    assert "needs ddqn_tuned" in md and "(exploratory, answers no question)" in md
    assert "## 4. Transfer" in md
    fig = analyse.protocol_figure(analyse.protocol_rows(scores), ["ddqn_tuned"])
    assert len(fig.axes) == 6


def test_rules_against_zero_and_between_intervals(analyse):
    assert analyse.zero_reading(-0.5, -0.01) == "below never"
    assert analyse.zero_reading(-0.5, 0.2) == "not distinguishable from never"
    assert analyse.apart(0.1, 0.3, 0.25, 0.5, 5) == "overlap: not distinguishable with 5 seeds"
    assert analyse.apart(0.6, 0.7, 0.25, 0.5, 5) == "higher (intervals apart)"


def test_a_bad_path_is_one_line(analyse, tmp_path: Path, capsys):
    assert analyse.main(["--archives-dir", str(tmp_path / "nowhere"), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: --archives-dir") and "no such folder" in err[0]
    (tmp_path / "empty").mkdir()
    assert analyse.main(["--archives-dir", str(tmp_path), "--paper-dir", str(tmp_path / "empty")]) == 2
    assert "no archives" in capsys.readouterr().err
