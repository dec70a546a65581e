"""reports/ladder/analyse.py: the ladder's tables follow the plan's rule and paired description,
say "not yet run" for an absent archive, read the late meals and the learning-curve drift, and
(slow) make its tables and figure from real archives of short runs at two observation levels."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from report_scripts import load_script

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def ladder():
    return load_script("ladder", "analyse")


def _batch(ladder, arm, shares: dict[str, list[float]], device: str = "cpu", learning=None):
    rows = [
        dict(
            regime=r, seed=3800 + i, **{"return": -20 + 16 * s}, never=-20.0, planner=-4.0, score=s, foods=3.0, late=0.1
        )
        for r, ss in shares.items()
        for i, s in enumerate(ss)
    ]
    return ladder.Batch(arm, pd.DataFrame(rows), learning if learning is not None else pd.DataFrame(), device)


def _comparison(ladder, cid, regime, batches):
    cells = {(arm, r): ladder.cell_row(b, r) for arm, b in batches.items() for r in b.per_seed["regime"].unique()}
    return ladder.comparison_row(cid, regime, cells, batches)


def test_the_rule_moves_only_where_intervals_are_apart_and_pairs_by_seed(ladder):
    rng = np.random.default_rng(0)
    low = list(0.1 + rng.normal(0, 0.03, 10))
    high = list(0.8 + rng.normal(0, 0.03, 10))
    near = [v + 0.01 * (-1) ** i for i, v in enumerate(low)]
    b1 = _batch(ladder, ("ppo", 1), {"run3": low})
    b4 = _batch(ladder, ("ppo", 4), {"run3": high}, device="cuda:0")
    b2 = _batch(ladder, ("ppo", 2), {"run3": near})
    c4 = _comparison(ladder, "C4", "run3", {b.arm: b for b in (b1, b4)})
    assert c4["reading"] == "moves: higher (intervals apart)"
    assert c4["seeds_in_direction"] == 10 and c4["paired_seeds"] == 10
    assert c4["diff_lo"] > 0.6 and c4["devices"] == "cuda:0 / cpu"
    c1 = _comparison(ladder, "C1", "run3", {b.arm: b for b in (b1, b2)})
    assert c1["reading"] == "not distinguishable with 10 seeds"
    assert c1["seeds_in_direction"] < 10
    # the planner comparison: 100 % against an interval wholly below it
    c5 = _comparison(ladder, "C5", "run3", {b.arm: b for b in (b1, b4)})
    assert c5["reading"] == "moves: lower (intervals apart)" and c5["b_text"] == "100"
    # an absent archive is named, not computed
    c6 = _comparison(ladder, "C6", "run3", {b.arm: b for b in (b1, b4)})
    assert c6["reading"] == "not yet run: needs obs1_gru_ppo" and "a_text" not in c6


def test_a_seed_without_a_score_is_left_out_not_counted(ladder):
    shares = [0.1 * i for i in range(1, 10)] + [float("nan")]
    row = ladder.cell_row(_batch(ladder, ("ppo", 1), {"run3": shares}), "run3")
    assert row["seeds"] == 9 and row["iqm"] == pytest.approx(0.5) and np.isfinite(row["lo"])
    assert row["per_seed"].endswith("n/a")
    other = _batch(ladder, ("ppo", 2), {"run3": [0.5] * 10})
    c1 = _comparison(ladder, "C1", "run3", {b.arm: b for b in (other, _batch(ladder, ("ppo", 1), {"run3": shares}))})
    assert c1["paired_seeds"] == 9 and c1["reading"].endswith("with 9 seeds")


def test_late_meals_count_the_last_five_steps_of_the_day(ladder):
    steps = pd.DataFrame(dict(regime="run3", seed=3800, step=[1, 10, 45, 46, 50, 50], action=[1, 1, 1, 1, 1, 0]))
    late = ladder.late_share(steps)
    assert late["late"].tolist() == [pytest.approx(2 / 5)]


def test_late_drift_is_read_off_the_learning_curve(ladder):
    days = [100, 200, 300]
    drift = pd.DataFrame(
        dict(regime="run6", algo="ppo", train_day=days, iqm=[0.2, 0.7, 0.1], lo=[0.1, 0.6, 0.0], hi=[0.3, 0.8, 0.2])
    )
    row = ladder.cell_row(_batch(ladder, ("ppo", 1), {"run6": [0.1] * 10}, learning=drift), "run6")
    assert (row["best_day"], row["last_day"], row["late_drift"]) == (200, 300, True)
    flat = drift.assign(lo=[0.1, 0.3, 0.0], hi=[0.3, 0.8, 0.5])
    row = ladder.cell_row(_batch(ladder, ("ppo", 1), {"run6": [0.1] * 10}, learning=flat), "run6")
    assert row["late_drift"] is False


def test_a_folder_without_the_plan_s_archives_is_one_line(ladder, tmp_path: Path, capsys):
    assert ladder.main(["--archives-dir", str(tmp_path / "nowhere")]) == 2
    assert "no such folder" in capsys.readouterr().err
    (tmp_path / "other.npz").write_bytes(b"")
    assert ladder.main(["--archives-dir", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "none of the plan's archives" in capsys.readouterr().err


@pytest.mark.slow
def test_tables_and_figure_from_real_archives_at_two_levels(ladder, tmp_path: Path, monkeypatch, capsys):
    from typer.testing import CliRunner

    from nutribench.cli import app

    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(ROOT / "reports" / "ladder" / "agents"))
    data = tmp_path / "data"
    data.mkdir()
    for level in (1, 4):
        monkeypatch.setenv("NUTRIBENCH_REGIMES", str(ladder.level_folder(level)))
        db = str(tmp_path / f"obs{level}.db")
        args = ["run", "--engine", "batched", "--device", "cpu", "--regimes", "run0,run3,run6", "--seeds", "3800,3801",
                "--episodes", "2", "--eval-episodes", "2", "--eval-every", "1", "--workers", "1", "--algos", "ppo", "--db", db]  # fmt: skip
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        res = CliRunner().invoke(app, ["db", "export", str(data / f"obs{level}_ppo.npz"), "--db", db, "--algos", "ppo"])
        assert res.exit_code == 0, res.output
    monkeypatch.delenv("NUTRIBENCH_REGIMES")
    out = tmp_path / "out"
    assert ladder.main(["--archives-dir", str(data), "--out", str(out)]) == 0
    cells = pd.read_csv(out / "table_ladder.csv")
    assert sorted(zip(cells["level"], cells["regime"])) == [(lv, r) for lv in (1, 4) for r in ("run0", "run3", "run6")]
    assert (cells["seeds"] == 2).all() and cells["iqm"].notna().all() and (cells["device"] == "cpu").all()
    assert cells["best_day"].notna().all()  # the evaluations during training were read
    comps = pd.read_csv(out / "table_comparisons.csv")
    c4 = comps[comps["id"] == "C4"]
    assert len(c4) == 3 and c4["reading"].str.contains("not distinguishable|moves").all()
    assert comps.loc[comps["id"] == "C7", "reading"].str.startswith("not yet run: needs obs1_gru_ppo").all()
    text = (out / "table_ladder.md").read_text()
    assert "not the plan's jobs" in text and "obs4_gru_ppo" in text
    assert (out / "fig_ladder.png").stat().st_size > 10_000
    # an archive under another level's name is refused in one line (its regimes are level 1's)
    wrong = tmp_path / "wrong"
    wrong.mkdir()
    (wrong / "obs2_ppo.npz").write_bytes((data / "obs1_ppo.npz").read_bytes())
    assert ladder.main(["--archives-dir", str(wrong), "--out", str(tmp_path / "out2")]) == 2
    assert "run0 v2, run3 v2, run6 v2, but level 2's files" in capsys.readouterr().err


def test_the_tuned_ppo_arm_runs_the_tuning_study_s_file_unchanged():
    """Addendum 1: the tuned PPO arm is ``reports/tuned/agents/ppo_tuned.toml`` copied byte for byte."""
    copy = ROOT / "reports" / "ladder" / "agents" / "ppo_tuned.toml"
    assert copy.read_bytes() == (ROOT / "reports" / "tuned" / "agents" / "ppo_tuned.toml").read_bytes()


def test_the_figure_draws_every_arm_of_the_plan(ladder):
    """All twelve batches (GRU-PPO arms as markers at levels 1 and 4, learning curves per batch)."""
    curve = pd.DataFrame(
        [dict(regime=r, algo="x", train_day=d, iqm=0.5, lo=0.4, hi=0.6) for r in ladder.REGIMES for d in (100, 200)]
    )
    batches = {
        (arm, level): _batch(ladder, (arm, level), {r: [0.1 * level] * 10 for r in ladder.REGIMES}, learning=curve)
        for arm, levels in ladder.ARMS.items()
        for level in levels
    }
    cells = pd.DataFrame([ladder.cell_row(b, r) for b in batches.values() for r in ladder.REGIMES])
    fig = ladder.figure(cells, batches)
    top, bottom = fig.axes[0], fig.axes[len(ladder.REGIMES)]
    labels = top.get_legend_handles_labels()[1]
    assert {"PPO", "tuned PPO", "GRU-PPO", "GRU-PPO without memory"} <= set(labels)
    assert len(bottom.get_lines()) == 12 + 2  # one curve per batch, never and the planner


def test_a_batch_started_on_a_gpu_says_so(ladder, tmp_path: Path):
    """Addendum 2: a batch whose log says it started on a lent GPU is labelled with both devices."""
    log = tmp_path / "obs1_gru_ppo.txt"
    assert ladder.started_on("cpu", log) == "cpu"  # no log
    log.write_text("2026-11-27\nbatch obs1_gru_ppo, device cpu\n")
    assert ladder.started_on("cpu", log) == "cpu"
    log.write_text(
        "== GPU start (addendum 2): ...\n== checkpoint brought back: 151,500 of 250,000 steps (day 3030 of 5000)\n"
    )
    assert ladder.started_on("cpu", log) == "cuda to day 3030, then cpu"
    log.write_text("== GPU start (addendum 2): ...\n== checkpoint brought back: (day 1200 of 5000)\n")
    assert ladder.started_on("cpu", log) == "cuda to day 1200, then cpu"  # the day is read, not assumed
    log.write_text("resumed from a checkpoint (day 1200 of 5000)\n")
    assert ladder.started_on("cpu", log) == "cpu"  # a day without the GPU start is not a GPU batch


def test_addendum_3_s_files_are_ppo_with_one_setting_changed():
    """Addendum 3: ``ppo_nonorm`` and ``ppo_mb250`` are the plan's ``ppo.toml`` with their own name
    and description and one setting each (observation normalisation off; five-day minibatches)."""
    from nutribench.agents.config import load_agent_config

    agents = ROOT / "reports" / "ladder" / "agents"
    base = load_agent_config(agents / "ppo.toml").model_dump()
    for name, changed in (("ppo_nonorm", {"normalize_obs": False}), ("ppo_mb250", {"batch_size": 250})):
        cfg = load_agent_config(agents / f"{name}.toml").model_dump()
        differs = {k for k in base if cfg[k] != base[k]}
        assert differs == {"name", "description", *changed}, name
        assert all(cfg[k] == v for k, v in changed.items()) and cfg["name"] == name


def test_the_follow_up_refuses_a_folder_without_its_archives_in_one_line(ladder, tmp_path: Path, capsys):
    followup = load_script("ladder", "followup")
    assert followup.main(["--archives-dir", str(tmp_path / "nowhere")]) == 2
    assert "no such folder" in capsys.readouterr().err
    assert followup.main(["--archives-dir", str(tmp_path), "--out", str(tmp_path / "out")]) == 2
    assert "none of the follow-up's archives" in capsys.readouterr().err
    (tmp_path / "a_file").write_text("")  # analyse.py's command line, shared: an --out that is a file is one line
    assert followup.main(["--archives-dir", str(tmp_path), "--out", str(tmp_path / "a_file")]) == 2
    assert "not a folder" in capsys.readouterr().err
    # its own copy of analyse.py: the plan's comparisons are untouched
    assert set(followup.ladder.COMPARISONS) == {f"F{i}" for i in range(1, 8)} and followup.ladder is not ladder
    assert len(ladder.COMPARISONS) == 18 and "F1" not in ladder.COMPARISONS
