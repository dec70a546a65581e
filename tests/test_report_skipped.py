"""``report --all`` draws what the database holds (issue 75): Figure 4 only with results of
both agents it compares, the config tables only of agents with results, Figure 6 only with
evaluations during training; each item left out is one line saying what and why."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.report.build import FIGURES
from tests.conftest import one_error_line
from tests.test_report_cli import make_db

runner = CliRunner()


@pytest.mark.slow  # about 90 s on a loaded 2-core machine (six figures, nine tables, the page)
def test_all_skips_each_item_the_database_does_not_hold_with_one_line(tmp_path: Path):
    # PPO and a user's agent, no GRU-PPO, no MC/DDQN/SAC, no evaluations during training
    db = make_db(
        tmp_path / "ppo.db",
        regimes=("run3",),
        algos=("ppo", "mine"),
        seeds=(0, 1),
        budgets=(10,),
        eval_eps=3,
        steps=False,
        eval_every=0,
    )
    out = tmp_path / "r"
    res = runner.invoke(app, ["report", "--all", "--db", str(db), "--out", str(out), "--reference-episodes", "2"])
    assert res.exit_code == 0, res.output
    skipped = [line for line in res.output.splitlines() if line.startswith("skipped:")]
    assert skipped == [
        "skipped: table 2 (mc): no results of mc in the database (--table 2 builds it all the same)",
        "skipped: table 3 (ddqn): no results of ddqn in the database (--table 3 builds it all the same)",
        "skipped: table 5 (sac): no results of sac in the database (--table 5 builds it all the same)",
        "skipped: table 6 (gru_ppo): no results of gru_ppo in the database (--table 6 builds it all the same)",
        "skipped: figure 4: no evaluation episodes for GRU-PPO in the database (the figure compares PPO against "
        "GRU-PPO; --pair A,B compares two it holds)",
        "skipped: figure 6: no evaluations during training (run with --eval-every N)",
    ], res.output
    names = {p.name for p in out.iterdir()}
    assert f"{FIGURES[4]}.png" not in names and f"{FIGURES[6]}.png" not in names
    assert {f"{FIGURES[n]}.png" for n in (1, 2, 3, 5)} <= names
    assert {"table4_ppo.md", "table7_mine.md"} <= names
    assert not {"table2_mc.md", "table3_ddqn.md", "table5_sac.md", "table6_gru_ppo.md"} & names
    # asked for by number, a config table is built from its file; Figure 4 is one error line
    res = runner.invoke(app, ["report", "--table", "2", "--db", str(db), "--out", str(tmp_path / "t")])
    assert res.exit_code == 0 and (tmp_path / "t" / "table2_mc.md").exists(), res.output
    line = one_error_line(runner.invoke(app, ["report", "--fig", "4", "--db", str(db), "--out", str(tmp_path / "f")]))
    assert "no evaluation episodes for GRU-PPO" in line and "--pair" in line
    assert not (tmp_path / "f").exists()


def test_the_tables_of_configs_without_results_are_the_ones_left_out():
    import pandas as pd

    from nutribench.report.build import table_plan, unheld_tables

    plan = table_plan([], True, {"ppo": None, "mine": None, "idle": None}, None)
    assert list(plan) == ["1", "2", "3", "4", "5", "6", "7", "8", "results", "training", "aggregate"]
    metrics = pd.DataFrame({"algo": ["ppo", "mine"]})
    why = unheld_tables(plan, {"ppo": None, "mine": None, "idle": None}, metrics)
    assert sorted(why) == ["2", "3", "5", "6", "7"]  # 7: idle, a stored config without results
    assert why["7"].startswith("table 7 (idle): no results of idle in the database")
    assert "3" not in unheld_tables(plan, None, metrics, asked=["ddqn"])  # asked for by name: kept


def test_figure_4_with_one_of_its_pair_is_one_error_line(tmp_path: Path):
    from nutribench.report.build import ReportError, build_figure, load_report_data

    db = make_db(
        tmp_path / "ppo.db",
        regimes=("run3",),
        algos=("ppo",),
        seeds=(0,),
        budgets=(4,),
        eval_eps=2,
        steps=False,
        eval_every=0,
    )
    with pytest.raises(
        ReportError,
        match=r"^figure 4: no evaluation episodes for GRU-PPO in the database \(the figure compares PPO against GRU-PPO",
    ):
        build_figure(4, load_report_data(db), reference_episodes=2)
