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
