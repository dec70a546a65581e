"""Bad inputs to ``nutribench run``: each is one line, exit 2, no
traceback, and nothing created (no database, no models folder), before any job starts."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.scheduler.grid import MAX_SEED, GridError, parse_seeds
from tests.conftest import run_cli_args
from tests.test_scheduler import regimes  # noqa: F401 - the fixture


def run(tmp_path: Path, *args: str):
    db = tmp_path / "r.db"
    res = CliRunner().invoke(
        app,
        run_cli_args(db, *args, seeds=None, episodes=2),
        env={"NUTRIBENCH_JOB": "fake"},
    )
    return res, db


def one_line_exit_2(res) -> str:
    assert res.exit_code == 2, (res.exit_code, res.output, res.exception)
    assert "Traceback" not in res.output and len(res.output.strip().splitlines()) == 1, res.output
    return res.output


@pytest.mark.parametrize(
    ("seeds", "message"),
    [
        ("99999999999999999999999", "seed 99999999999999999999999 is too large: seeds go from 0 to 2147483647"),
        ("0,2147483648", "seed 2147483648 is too large"),
        ("0,²", "'²' is not a non-negative integer"),
    ],
)
def test_a_seed_too_large_for_the_database_is_one_line_and_creates_nothing(regimes, tmp_path, seeds, message):
    """``--seeds 99999999999999999999999`` was an OverflowError traceback, after the database was created."""
    res, db = run(tmp_path, "--seeds", seeds)
    assert message in one_line_exit_2(res).replace("\n", "")
    assert not db.exists() and not (tmp_path / "models").exists()


def test_the_largest_seed_is_accepted():
    assert parse_seeds(f"0,{MAX_SEED}") == (0, MAX_SEED)
    with pytest.raises(GridError, match="too large"):
        parse_seeds(str(MAX_SEED + 1))


@pytest.mark.parametrize("where", ["models-file", "models-file/sub", "default"])
def test_a_models_folder_that_is_a_file_is_one_line_before_any_job(regimes, tmp_path, where):
    """``--models-dir`` naming a file was not checked: each job trained, then failed to save,
    three times. Now it is refused before the database exists (and so is a default ``models/``
    next to the database that is a file)."""
    notes = tmp_path / ("models" if where == "default" else "models-file")
    notes.write_text("not a folder\n")
    args = [] if where == "default" else ["--models-dir", str(tmp_path / where)]
    res, db = run(tmp_path, "--seeds", "0", *args)
    out = one_line_exit_2(res).replace("\n", "")
    assert "is a file, not a folder" in out and "give a folder for the trained models" in out, out
    assert not db.exists() and notes.read_text() == "not a folder\n"


def test_a_models_folder_that_is_a_folder_runs(regimes, tmp_path):
    res, db = run(tmp_path, "--seeds", "0", "--models-dir", str(tmp_path / "new" / "models"))
    assert res.exit_code == 0, res.output
    assert db.exists()
