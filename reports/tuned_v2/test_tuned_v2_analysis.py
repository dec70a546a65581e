"""reports/tuned_v2/analyse.py's G5 difference: the v2 file's drop from the delayed tuning regimes
to the held-out ones minus its paper file's, the runs paired by seed."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from report_scripts import load_script

SEEDS = (0, 21, 9, 2003, 1997)


@pytest.fixture(scope="module")
def analyse():
    return load_script("tuned_v2", "analyse")


def _scores(analyse, lift_on_tuning: float) -> pd.DataFrame:
    """The paper file's scores drawn at random per regime and seed; the v2 file's the same runs
    plus ``lift_on_tuning`` on the delayed tuning regimes."""
    rng = np.random.default_rng(3)
    rows = []
    for r in (*analyse.TUNING_DELAYED, *analyse.HELD_OUT):
        for seed in SEEDS:
            paper = float(rng.normal(0.3, 0.4))
            lift = lift_on_tuning if r in analyse.TUNING_DELAYED else 0.0
            rows += [
                {"regime": r, "algo": "ppo", "seed": seed, "score": paper},
                {"regime": r, "algo": "ppo_tuned_v2", "seed": seed, "score": paper + lift},
            ]
    return pd.DataFrame(rows)


def test_the_difference_of_drops_pairs_each_run_with_its_seed(analyse):
    scores = _scores(analyse, 0.25)
    d = analyse.transfer_difference(scores, "ppo_tuned_v2", "ppo")
    a, b = (analyse.transfer(scores, n) for n in ("ppo_tuned_v2", "ppo"))
    assert d["point"] == pytest.approx(a["point"] - b["point"], abs=1e-12)
    # paired by seed, each pair differs by exactly the lift: no spread, so the interval is 0.25
    # (to the rounding of a mean of five numbers), where the two files' own drops vary by tenths
    assert d["lo"] == pytest.approx(0.25, abs=1e-9) and d["hi"] == pytest.approx(0.25, abs=1e-9)
    assert a["hi"] - a["lo"] > 0.1
    assert analyse.difference_reading(d["lo"], d["hi"]).startswith("the v2 file drops more")


def test_no_difference_without_the_same_seeds_on_every_regime(analyse):
    scores = _scores(analyse, 0.0)
    one_fewer = scores[~((scores["algo"] == "ppo") & (scores["regime"] == "run3") & (scores["seed"] == 9))]
    assert analyse.transfer_difference(one_fewer, "ppo_tuned_v2", "ppo") is None
    no_held = scores[scores["regime"] != "run6"]
    assert analyse.transfer_difference(no_held, "ppo_tuned_v2", "ppo") is None
    assert analyse.difference_reading(-0.1, 0.2) == "holds 0: not distinguishable"


def test_out_may_name_a_folder_not_yet_there(analyse, tmp_path, monkeypatch):
    """``--out`` to a new folder makes it (as ``--db`` makes its database), not a traceback at the
    first write after minutes of imports; the imports and tables are stubbed out here."""
    seen = []

    def tables(db, out, db3):
        seen.append(out.is_dir())
        return []

    monkeypatch.setattr(analyse.v1, "import_archives", lambda paths, db: None)
    monkeypatch.setattr(analyse, "analyse", tables)
    out = tmp_path / "new" / "deeper"
    assert analyse.main(["--out", str(out), "--db", str(tmp_path / "v2.db")]) == 0
    assert seen == [True]
    in_the_way = tmp_path / "a_file"
    in_the_way.write_text("")
    assert analyse.main(["--out", str(in_the_way)]) == 2 and seen == [True]


def test_per_run_counts_the_delayed_runs_that_ate_nothing_on_every_test_day(analyse):
    """A run counts as never eating only when every test day ate nothing: one day with a food
    keeps it out, run0's runs are not counted, and each cell shows the run's share and foods."""
    rows, ev = [], []
    for r in ("run0", "run1", "run2"):
        for seed in (0, 9):
            empty = (r, seed) in {("run0", 0), ("run1", 0), ("run2", 9)}
            rows.append({"regime": r, "algo": "sac_tuned_v2", "seed": seed, "score": 0.0 if empty else -1.5})
            foods = [0, 0] if empty else [3, 5]
            if (r, seed) == ("run2", 9):
                foods = [0, 1]  # one food on one day: it ate
            ev += [{"regime": r, "algo": "sac_tuned_v2", "seed": seed, "foods": f} for f in foods]
    lines = analyse.per_run(pd.DataFrame(ev), pd.DataFrame(rows), ["sac_tuned_v2"])
    assert "**sac_tuned_v2**: 1 of 4 delayed runs ate nothing on every test day." in lines
    assert "| run1 | 0 (0.0) | -150 (4.0) |" in lines
    assert "| run2 | -150 (4.0) | 0 (0.5) |" in lines


def test_modes_counts_runs_that_switch_between_eating_nothing_and_much():
    """A run's validation points read as nothing (0 foods), much (>= 20) or neither (skipped):
    one that goes nothing -> much -> (10, skipped) -> nothing changes twice; one that stays at
    much, or only touches 10, never changes."""
    modes = load_script("tuned_v2", "modes").modes
    rows = []
    for seed, foods in {0: [0, 25, 10, 0], 1: [30, 22, 40, 21], 2: [0, 10, 0, 0]}.items():
        rows += [{"regime": "run5", "seed": seed, "train_day": 250 * (k + 1), "foods": f} for k, f in enumerate(foods)]
    # two validation days at one point: their mean (0 and 40 -> 20, much) is the point's
    rows += [{"regime": "run6", "seed": 0, "train_day": 250, "foods": f} for f in (0, 40)]
    rows += [{"regime": "run6", "seed": 0, "train_day": 500, "foods": 0}]
    table = modes(pd.DataFrame(rows))
    assert table.loc["run5"].tolist() == [3, 1, 0]  # 3 runs, 1 at both, median changes of (2, 0, 0)
    assert table.loc["run6"].tolist() == [1, 1, 1]
