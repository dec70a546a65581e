"""Output scripts can read, in one unit (issue 54): ``tune status --json``, ``compare --json``
and ``leaderboard --format json``; ``tune`` prints shares of the gap in percent, as the
leaderboard does; ``compare`` prints a warning as ``warning:``, not ``note: warning:``."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.report.compare import _note_line
from tests.test_leaderboard import _recorded_db

runner = CliRunner()


def test_leaderboard_and_compare_speak_json(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    _recorded_db(db, {"eat_early": (0, 21), "never_eat": (0, 21)})
    board = runner.invoke(app, ["leaderboard", "--db", str(db), "--format", "json", "--reps", "200"])
    assert board.exit_code == 0, board.output
    data = json.loads(board.output)
    # the agents ranked, then the references above the planner (unranked: regimes/references.csv)
    assert [r["algo"] for r in data["rows"]] == ["eat_early", "never_eat", "lookahead", "clairvoyant"]
    assert [r["rank"] for r in data["rows"]][2:] == [None, None] and "caption" in data
    cmp = runner.invoke(app, ["compare", "eat_early", "never_eat", "--db", str(db), "--json", "--reps", "200"])
    assert cmp.exit_code == 0, cmp.output
    out = json.loads(cmp.output)
    assert out["a"] == "eat_early" and out["b"] == "never_eat" and out["rows"][0]["regime"] == "run0"


def test_tune_speaks_percent_and_json(tmp_path: Path) -> None:
    db = tmp_path / "t.db"
    args = ["--regimes", "run3", "--seeds", "101", "--days", "2", "--eval-every", "1", "--val-episodes", "1"]
    res = runner.invoke(app, ["tune", "--db", str(db), "--algo", "ppo", "--study", "s", "--trials", "1", *args])
    assert res.exit_code == 0, res.output
    assert "IQM share of the gap" in res.output and "%" in res.output.split("IQM share of the gap")[1].splitlines()[0]
    status = runner.invoke(app, ["tune", "status", "--db", str(db), "--json"])
    assert status.exit_code == 0, status.output
    (study,) = json.loads(status.output)
    assert study["study"] == "s" and study["complete"] == 1 and study["settings"]["days"] == 2


def test_a_warning_prints_once_as_a_warning() -> None:
    assert _note_line("warning: budgets differ") == "warning: budgets differ"
    assert _note_line("run3 left out") == "note: run3 left out"
