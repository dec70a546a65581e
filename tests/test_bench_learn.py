"""`python benchmarks/learn.py`: the gap arithmetic, the budgets, and the command's shape (its
figures are a benchmark's, not a test's)."""

from __future__ import annotations

import re

import pytest
from typer.testing import CliRunner

from tests.conftest import benchmark_script

learn = benchmark_script("learn")
LearnRun, budget_for, markdown_table, summarize_runs = (
    learn.LearnRun,
    learn.budget_for,
    learn.markdown_table,
    learn.summarize_runs,
)
iqm, parse_budgets, app = learn.iqm, learn.parse_budgets, learn.app  # iqm: the report's, reused

runner = CliRunner()


def _run(algo, regime, seed, returns, foods, never=-20.0, planner=-4.0):
    rows = [{"return": r, "foods": f, "final_distance": 1.0, "overshoot_ratio": 0.0} for r, f in zip(returns, foods)]
    return LearnRun(algo, regime, seed, 500, 1.0, rows, [never] * len(rows), [planner] * len(rows))


def test_gap_closed_is_zero_for_never_one_for_the_planner_and_checks_the_target():
    runs = [
        _run("ppo", "run0", 0, [-4.0, -4.0], [4, 4]),
        _run("ppo", "run0", 1, [-12.0, -12.0], [4, 5]),
        _run("mc", "run0", 0, [-20.0], [0]),
        _run("ppo", "run3", 0, [-4.0], [4]),
    ]
    rows = {(r["regime"], r["algo"]): r for r in summarize_runs(runs)}
    ppo = rows[("run0", "ppo")]
    assert ppo["gap_closed"] == pytest.approx(0.75) and ppo["gap_closed_min_seed"] == pytest.approx(0.5)
    assert ppo["target_met"] is True and ppo["foods"] == pytest.approx(4.25)
    assert rows[("run0", "mc")]["gap_closed"] == 0.0 and rows[("run0", "mc")]["target_met"] is False
    assert rows[("run3", "ppo")]["target_met"] is None  # targets are set on run0 only
    assert "| run0 | ppo | 500 | 2 |" in markdown_table(list(rows.values()))


def test_no_gap_to_close_is_nan_not_a_crash():
    import math

    (row,) = summarize_runs([_run("ppo", "run0", 0, [-4.0], [4], never=-4.0, planner=-4.0)])
    assert math.isnan(row["gap_closed"]) and row["target_met"] is False


def test_iqm_is_the_mean_of_the_middle_half():
    assert iqm([0, 1, 2, 3, 4, 5, 6, 100]) == pytest.approx(3.5)


def test_budgets_by_name_then_algorithm():
    assert parse_budgets("500,ddqn=2000", 100) == (500, {"ddqn": 2000})
    assert budget_for("ddqn_fast", "ddqn", {"ddqn": 2000}, 500) == 2000
    assert budget_for("ddqn_fast", "ddqn", {"ddqn_fast": 300, "ddqn": 2000}, 500) == 300
    assert budget_for("ppo", "ppo", {"ddqn": 2000}, 500) == 500


@pytest.mark.parametrize("bad", ["abc", "ppo=x", "0", "ppo=-3", "500,pp0=300"])
def test_a_bad_budget_is_one_line_and_exit_2(bad):
    res = runner.invoke(app, ["--episodes", bad])
    assert res.exit_code == 2 and "--days" in res.output and len(res.output.strip().splitlines()) == 1, res.output


def test_bench_learn_runs_and_prints_its_table():
    res = runner.invoke(
        app,
        [
            "--algos",
            "ppo",
            "--regimes",
            "run0",
            "--seeds",
            "0",
            "--episodes",
            "2",
            "--eval-episodes",
            "2",
            "--workers",
            "1",
            "--markdown",
        ],
    )
    assert res.exit_code == 0, res.output
    assert "| run0 | ppo | 2 | 1 |" in res.output and "gap closed" in res.output


@pytest.mark.parametrize("bad", ["0,0", "a", "-1", ""])
def test_bad_seeds_are_one_line_and_exit_2(bad):
    res = runner.invoke(app, ["--seeds", bad])
    assert res.exit_code == 2 and "--seeds" in res.output and len(res.output.strip().splitlines()) == 1, res.output


def test_bench_learn_with_the_batched_engine_and_its_limits(monkeypatch) -> None:
    res = CliRunner().invoke(
        app,
        [
            "--algos",
            "mc,ppo,sac",
            "--regimes",
            "run0",
            "--seeds",
            "0,1",
            "--episodes",
            "2",
            "--eval-episodes",
            "1",
            "--engine",
            "batched",
            "--markdown",
        ],
    )
    assert res.exit_code == 0, res.output
    assert all(f"| run0 | {a} | 2 | 2 |" in res.output for a in ("mc", "ppo", "sac"))
    # an algorithm the engine would not train (all five are in it today) is refused in one line
    monkeypatch.setattr("nutribench.agents.registry.batched_names", lambda: ["ppo", "mc"])
    bad = CliRunner().invoke(app, ["--algos", "sac", "--engine", "batched"])
    assert bad.exit_code == 2 and "use --engine sb3" in bad.output


@pytest.mark.parametrize("name", ["learn", "engines", "status"])
def test_the_moved_bench_commands_say_where_they_went_in_one_line(name: str) -> None:
    """``nutribench bench NAME`` (before it moved to ``benchmarks/NAME.py``), with its old options:
    one line naming the script, exit 2, and hidden from ``bench --help``."""
    from nutribench.cli import app as nutribench_app

    res = runner.invoke(nutribench_app, ["bench", name, "--seeds", "0,1", "--markdown"])
    lines = res.output.strip().splitlines()
    assert res.exit_code == 2 and len(lines) == 1 and f"python benchmarks/{name}.py" in lines[0], res.output
    listed = runner.invoke(nutribench_app, ["bench", "--help"]).output
    listed_names = re.findall(r"^  ([a-z]+)\b", listed.partition("Commands:")[2], re.M)
    assert name not in listed_names and "env" in listed_names, listed
