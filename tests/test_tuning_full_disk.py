"""Issue 74, a full disk under ``tune``: a write the study's database refuses ("database or disk
is full") stops the driver with one line, and its trial is failed at once, not left RUNNING
until the grace period ends. The full disk is injected where SQLite would report it: a
statement of Optuna's storage raises ``sqlite3.OperationalError("database or disk is full")``
(SQLAlchemy and Optuna wrap it on its way up, as on a real full disk). Nothing trains."""

from __future__ import annotations

import re
import sqlite3
from pathlib import Path
from types import SimpleNamespace

import optuna
import pytest
from sqlalchemy import event
from typer.testing import CliRunner

import nutribench.tuning.study as study_module
from nutribench.cli import app
from nutribench.tuning.stack import run_study
from nutribench.tuning.study import TuneError, open_study
from tests.conftest import one_error_line, tiny_study_settings

runner = CliRunner()
FULL = "database or disk is full"
TINY = ["--regimes", "run3", "--seeds", "101", "--days", "4", "--eval-every", "2", "--val-episodes", "1"]


def quick(trial) -> float:
    """An objective that trains nothing: the study machinery alone."""
    return trial.suggest_float("x", 0.0, 1.0)


def fill_disk(storage, *statements: str, until_checkpoint: bool = False):
    """Make every statement of the RDB storage ``storage`` (or a study's) whose SQL (upper case,
    on one line) matches one of the regular expressions ``statements`` fail as SQLite fails on a
    full disk (``until_checkpoint``: until a WAL checkpoint has emptied the log, which frees its
    space); returns the undo."""
    storage = getattr(storage, "_storage", storage)  # a study's storage: Optuna's cache around the RDB one
    engine = getattr(storage, "_backend", storage).engine

    freed = []

    def refuse(conn, cursor, statement, parameters, context, executemany):
        sql = " ".join(statement.upper().split())
        if until_checkpoint and sql.startswith("PRAGMA WAL_CHECKPOINT(TRUNCATE)"):
            freed.append(sql)
        if not freed and any(re.match(s, sql) for s in statements):
            raise sqlite3.OperationalError(FULL)

    event.listen(engine, "before_cursor_execute", refuse)
    return lambda: event.remove(engine, "before_cursor_execute", refuse)


def states(db: Path, name: str) -> dict[int, str]:
    return {t.number: t.state.name for t in optuna.load_study(study_name=name, storage=f"sqlite:///{db}").trials}


def test_a_full_disk_while_a_trial_asks_fails_it_at_once_and_is_one_line(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    study = open_study(db, "f", tiny_study_settings())
    undo = fill_disk(study, "INSERT INTO TRIAL_PARAMS")  # space.py's suggest: the issue's failing write
    with pytest.raises(TuneError) as info:
        run_study(study, quick, 2)
    line = str(info.value)
    assert "\n" not in line and f"refused a write: {FULL}: trial 0 failed;" in line, line
    assert "run the same command again" in line
    assert states(db, "f") == {0: "FAIL"}  # failed at once, not RUNNING until the grace period ends
    undo()
    counts = run_study(study, quick, 2)  # disk freed: the rerun goes on
    assert (counts.complete, counts.failed) == (2, 1) and states(db, "f") == {0: "FAIL", 1: "COMPLETE", 2: "COMPLETE"}


def test_a_disk_too_full_to_fail_the_trial_leaves_it_to_the_stale_rule_and_says_so(tmp_path: Path) -> None:
    db = tmp_path / "lab.db"
    study = open_study(db, "f", tiny_study_settings())
    fill_disk(study, "INSERT INTO TRIAL_PARAMS", "UPDATE TRIALS SET .*DATETIME_COMPLETE")  # the FAIL too
    with pytest.raises(TuneError) as info:
        run_study(study, quick, 2)
    line = str(info.value)
    assert "\n" not in line and f"refused a write: {FULL}: trial 0 could not be marked failed" in line, line
    assert "runs its parameters again 120 s after the last heartbeat" in line, line
    assert states(db, "f") == {0: "RUNNING"}


def test_a_full_disk_whose_log_can_be_emptied_still_fails_the_trial_at_once(tmp_path: Path) -> None:
    """The failure's write is refused too, until SQLite's write-ahead log has been moved into the
    database and emptied (on a 2 MB tmpfs that freed the 40 kB the write needed): failed at once."""
    db = tmp_path / "lab.db"
    study = open_study(db, "f", tiny_study_settings())
    fill_disk(study, "INSERT INTO TRIAL_PARAMS", "UPDATE TRIALS SET .*DATETIME_COMPLETE", until_checkpoint=True)
    with pytest.raises(TuneError) as info:
        run_study(study, quick, 2)
    assert f"refused a write: {FULL}: trial 0 failed;" in str(info.value), info.value
    assert states(db, "f") == {0: "FAIL"}


@pytest.mark.parametrize("stack", [1, 2])
def test_tune_on_a_full_disk_is_one_line_exit_2_and_its_trials_are_failed(tmp_path: Path, monkeypatch, stack) -> None:
    db = tmp_path / "lab.db"
    real = study_module.optuna_storage

    def full_storage(*args, **kw):
        storage = real(*args, **kw)
        if storage is not None:
            fill_disk(storage, "INSERT INTO TRIAL_PARAMS")
        return storage

    monkeypatch.setattr(study_module, "optuna_storage", full_storage)
    args = ["tune", "--space", "ppo", "--study", "f", "--db", str(db), "--trials", "2", "--stack", str(stack), *TINY]
    res = runner.invoke(app, args)
    start, _, rest = res.output.partition("\n")  # tune's line saying what it starts, then the error
    assert start.startswith("tune f: search space ppo"), res.output
    line = one_error_line(SimpleNamespace(exit_code=res.exit_code, output=rest))
    assert f"the study's database refused a write: {FULL}: trial 0 failed;" in line, line
    assert states(db, "f") == {0: "FAIL"}
