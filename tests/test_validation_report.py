"""The learning-curve figure (``report --fig 6`` / ``--fig learning``) from the evaluations
during training: its numbers are the IQM over seeds of the run scores on the validation days,
with the aggregate figure's bootstrap; no such rows is one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from test_report_cli import invoke, make_db

from nutribench.report.learning import learning_curve_figure, learning_points, learning_scores
from nutribench.stats import iqm
from nutribench.store import read_learning_curve
from tests.conftest import one_error_line


def test_scores_and_points_are_the_iqm_over_seeds_of_the_run_scores(tmp_path: Path) -> None:
    db = make_db(tmp_path / "r.db", seeds=(0, 1, 2, 3), steps=False)
    curve = read_learning_curve(db)
    scores = learning_scores(curve)
    one = curve[(curve["regime"] == "run3") & (curve["algo"] == "ppo") & (curve["seed"] == 2)]
    day = one[one["train_day"] == 20]
    want = (day["return"].mean() - day["never"].mean()) / (day["planner"].mean() - day["never"].mean())
    got = scores[(scores["regime"] == "run3") & (scores["algo"] == "ppo") & (scores["seed"] == 2)]
    assert got[got["train_day"] == 20]["score"].item() == pytest.approx(want)
    points = learning_points(scores, reps=500)
    cell = scores[(scores["regime"] == "run0") & (scores["algo"] == "gru_ppo") & (scores["train_day"] == 30)]
    p = points[(points["regime"] == "run0") & (points["algo"] == "gru_ppo") & (points["train_day"] == 30)].iloc[0]
    assert p["iqm"] == pytest.approx(iqm(cell["score"].to_numpy())) and p["seeds"] == 4
    assert p["lo"] <= p["iqm"] <= p["hi"] and p["lo"] < p["hi"]
    assert sorted(set(points["train_day"])) == [10, 20, 30]


def test_one_job_per_run_and_one_seed_has_no_band(tmp_path: Path) -> None:
    db = make_db(tmp_path / "r.db", regimes=("run3",), algos=("ppo",), seeds=(5,), budgets=(20, 30), steps=False)
    res = learning_curve_figure(read_learning_curve(db), reps=200)
    assert sorted(res.data["train_day"]) == [10, 20, 30]  # the 30-day job's, not the 20-day one's too
    assert res.data["lo"].isna().all() and any("left out" in n for n in res.notes)


def test_report_fig_learning_writes_the_figure(tmp_path: Path) -> None:
    db = make_db(tmp_path / "r.db", steps=False)
    out = tmp_path / "out"
    result = invoke("--fig", "learning", "--db", str(db), "--out", str(out))
    assert result.exit_code == 0, result.output
    assert (out / "fig6_learning_curve.png").is_file() and (out / "fig6_learning_curve.pdf").is_file()
    plain = make_db(tmp_path / "plain.db", steps=False, eval_every=0)
    line = one_error_line(invoke("--fig", "6", "--db", str(plain), "--out", str(out)))
    assert "figure 6: no evaluations during training" in line and "--eval-every" in line


def test_the_figure_has_a_panel_per_regime_and_a_line_per_agent(tmp_path: Path) -> None:
    db = make_db(tmp_path / "r.db", steps=False)
    res = learning_curve_figure(read_learning_curve(db), reps=200)
    panels = [ax for ax in res.figure.axes if ax.get_visible()]
    assert [ax.get_title() for ax in panels] == ["run0", "run3"]
    # one line per agent, each with its own marker (the palette's second cue)
    assert all(
        len({ln.get_marker() for ln in ax.get_lines() if ln.get_marker() not in ("None", "", " ")}) == 2
        for ax in panels
    )
    assert isinstance(res.data, pd.DataFrame) and np.isfinite(res.data["iqm"]).all()
