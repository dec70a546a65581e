"""One name per idea (issue 54): training days are ``--days`` in ``run``, ``train``, ``bench
train``, ``benchmarks/learn.py`` and ``benchmarks/engines.py``, as in ``tune``; ``--episodes``, the old
spelling, still works and is hidden from the help; both at once with different values is one
line."""

from __future__ import annotations

import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from tests.conftest import benchmark_script, one_error_line

runner = CliRunner()
COMMANDS = [["run"], ["train"], ["bench", "train"], ["learn"], ["engines"], ["tune"]]


@pytest.mark.parametrize("command", COMMANDS, ids=" ".join)
def test_training_days_are_days_everywhere(command: list[str]) -> None:
    script = command[0] in ("learn", "engines")  # the developer's benchmarks: benchmarks/NAME.py
    cli, args = (benchmark_script(command[0]).app, []) if script else (app, command)
    res = runner.invoke(cli, [*args, "--help"], terminal_width=200)
    assert res.exit_code == 0 and "--days" in res.output, res.output
    assert "--episodes " not in res.output  # the old spelling is hidden (--eval-episodes is another idea)


def test_the_old_spelling_still_works_and_both_must_agree(tmp_path) -> None:
    ok = runner.invoke(app, ["train", "--algo", "mc", "--episodes", "1", "--eval-episodes", "1"])
    assert ok.exit_code == 0, ok.output
    line = one_error_line(runner.invoke(app, ["train", "--algo", "mc", "--days", "1", "--episodes", "2"]))
    assert "--days 1 and --episodes 2: give one" in line
    db = tmp_path / "x.db"
    line = one_error_line(
        runner.invoke(
            app, ["run", "--regimes", "run0", "--algos", "mc", "--days", "2", "--episodes", "3", "--db", str(db)]
        )
    )
    assert "old spelling of --days" in line and not db.exists()


def test_tune_names_its_search_space_space(tmp_path) -> None:
    """``--algo`` names an agent file in ``run`` and ``train``; ``tune`` takes a search space,
    ``--space`` (``--algo`` still works there, hidden)."""
    res = runner.invoke(app, ["tune", "--help"], terminal_width=200)
    assert "--space" in res.output and "--algo " not in res.output
    args = ["--regimes", "run3", "--seeds", "101", "--days", "2", "--eval-every", "1", "--val-episodes", "1"]
    db = tmp_path / "t.db"
    ok = runner.invoke(app, ["tune", "--db", str(db), "--algo", "mc", "--study", "s", "--trials", "1", *args])
    assert ok.exit_code == 0, ok.output
    line = one_error_line(
        runner.invoke(app, ["tune", "--db", str(db), "--space", "mc", "--algo", "ppo", "--study", "s"])
    )
    assert "old spelling of --space" in line


def test_bench_tune_also_takes_a_space_and_baselines_evaluation_days() -> None:
    """``bench tune`` draws from a search space: ``--space``, as ``tune`` (``--algo`` hidden);
    ``baselines`` plays evaluation days: ``--eval-episodes``, as ``run`` and ``train``
    (``--episodes`` hidden); both spellings at once with different values is one line."""
    res = runner.invoke(app, ["bench", "tune", "--help"], terminal_width=200)
    assert "--space" in res.output and "--algo " not in res.output
    line = one_error_line(runner.invoke(app, ["bench", "tune", "--space", "mc", "--algo", "ppo"]))
    assert "old spelling of --space" in line
    res = runner.invoke(app, ["baselines", "--help"], terminal_width=200)
    assert "--eval-episodes" in res.output and "--episodes " not in res.output
    new = runner.invoke(app, ["baselines", "--regimes", "run0", "--eval-episodes", "2", "--markdown"])
    old = runner.invoke(app, ["baselines", "--regimes", "run0", "--episodes", "2", "--markdown"])
    assert new.exit_code == 0 == old.exit_code and new.output == old.output, new.output
    line = one_error_line(runner.invoke(app, ["baselines", "--episodes", "2", "--eval-episodes", "3"]))
    assert "old spelling of --eval-episodes" in line
