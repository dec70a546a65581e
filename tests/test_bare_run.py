"""A bare ``nutribench run`` starts the paper grid (175 jobs x 5000 days, about 30 CPU-hours):
it says so and asks on a terminal; a script must say ``--yes`` or name a preset (issue 54)."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

import nutribench.cli.run as run_cli
from nutribench.cli import app
from nutribench.scheduler.grid import PRESETS, Grid
from tests.conftest import one_error_line

runner = CliRunner()


def test_a_bare_run_in_a_script_is_one_line_and_writes_nothing(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    line = one_error_line(runner.invoke(app, ["run", "--db", str(db)]))
    assert "175 jobs (7 regimes x 5 agents x 5 seeds) x 5000 days" in line and "--yes" in line
    assert "about 30 CPU-hours" in line
    assert not db.exists()


def test_a_bare_run_on_a_terminal_asks_and_no_stops_it(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.setattr(run_cli, "_interactive", lambda: True)
    db = tmp_path / "lab.db"
    res = runner.invoke(app, ["run", "--db", str(db)], input="n\n")
    assert res.exit_code == 1 and "Start the paper grid: 175 jobs" in res.output, res.output
    assert not db.exists()


def test_the_estimate_scales_with_the_agents_costs() -> None:
    paper = PRESETS["paper"]
    grid = Grid(("run0",), ("a", "b"), paper.seeds, paper.episodes, paper.eval_episodes)
    cheap, dear = grid.cpu_hours(lambda _: 1.0), grid.cpu_hours(lambda name: 5.0 if name == "b" else 1.0)
    assert cheap > 0 and dear == pytest.approx(3 * cheap, rel=1e-12)


@pytest.mark.parametrize(("argv", "answer"), [(["--yes"], None), ([], "y\n")])
def test_yes_or_a_yes_answer_starts_the_paper_grid(tmp_path: Path, monkeypatch, argv, answer) -> None:
    """``--yes`` starts the paper grid without a question, and so does "y" on a terminal (the
    grid itself replaced by a recorder: what reaches it is the paper's grid)."""
    started = []

    def recorder(settings, *args, **kwargs):
        started.append((tuple(settings.regimes), tuple(settings.algos), tuple(settings.seeds), settings.episodes))
        raise SystemExit(0)

    monkeypatch.setattr("nutribench.scheduler.driver.run_grid", recorder)
    monkeypatch.setattr(run_cli, "_interactive", lambda: answer is not None)
    res = runner.invoke(app, ["run", "--db", str(tmp_path / "lab.db"), *argv], input=answer)
    assert res.exit_code == 0, res.output
    paper = PRESETS["paper"]
    ((regimes, algos, seeds, days),) = started
    assert len(regimes) == 7 and algos == ("mc", "ddqn", "ppo", "sac", "gru_ppo")
    assert seeds == tuple(paper.seeds) and days == paper.episodes == 5000
    assert ("Start the paper grid" in res.output) == (answer is not None)  # asked only without --yes


def test_an_unknown_algorithm_says_where_agent_files_are_looked_for(tmp_path: Path, monkeypatch) -> None:
    mine = tmp_path / "my_agents"
    mine.mkdir()
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(mine))
    db = tmp_path / "lab.db"
    line = one_error_line(runner.invoke(app, ["run", "--algos", "bogus", "--preset", "smoke", "--db", str(db)]))
    assert line.startswith("error: unknown algorithm bogus: known are mc, ddqn, ppo, sac, gru_ppo"), line
    assert str(mine) in line and "regimes/agents" in line and "NUTRIBENCH_AGENTS=<folder>" in line
    assert not db.exists()
