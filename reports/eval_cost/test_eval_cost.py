"""reports/eval_cost/evalcost.py: both arms timed, and a period past the budget refused in one
line. This study's own check: ``python -m pytest -p no:cacheprovider reports/eval_cost``."""

from __future__ import annotations

import pytest
from report_scripts import load_script


@pytest.fixture(scope="module")
def evalcost():
    return load_script("eval_cost", "evalcost")


def test_bench_eval_cost_times_both_arms(evalcost) -> None:
    (row,) = evalcost.bench_eval_cost(["mc"], episodes=2, repeats=2, eval_every=1, val_episodes=1)
    assert row["evaluations"] == 2 and row["with_s"] > 0 and row["without_s"] > 0
    assert row["cost_ci"][0] <= row["cost"] <= row["cost_ci"][1] and "cpu_cost" in row


def test_a_period_past_the_budget_is_one_line(evalcost, capsys) -> None:
    assert evalcost.main(["--algos", "mc", "--days", "5", "--eval-every", "10"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["evalcost.py: --eval-every 10: more than --days 5, no evaluation would be timed"]
