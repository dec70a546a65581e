"""Storing finished jobs when the database pushes back: a disk that
fills or an I/O error while a job is stored, a read-only database, a write lock held past the
busy timeout, and the printed commands that must work when pasted without showing a password."""

from __future__ import annotations

import shutil
import sqlite3
import threading
from pathlib import Path

import pandas as pd
import pytest
from sqlalchemy.engine import make_url
from sqlalchemy.exc import OperationalError
from typer.testing import CliRunner

import nutribench.scheduler.driver as driver
import nutribench.store.schema as schema
from nutribench.cli import app
from nutribench.scheduler.driver import GridSettings, run_grid
from nutribench.scheduler.synthetic import synthetic_job
from nutribench.store.engine import StoreError, make_engine
from tests.conftest import run_cli_args

REPO = Path(__file__).resolve().parents[1]
SECRET = "s3cr3t-pw"


@pytest.fixture
def regimes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    folder = tmp_path / "regimes"
    shutil.copytree(REPO / "regimes", folder)
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(folder))
    monkeypatch.delenv("NUTRIBENCH_AGENTS", raising=False)
    monkeypatch.delenv("NUTRIBENCH_DB", raising=False)
    return folder


def sql(db: Path, query: str) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return con.execute(query).fetchall()
    finally:
        con.close()


def grid(db: Path, seeds=(0, 21), **kw):
    return run_grid(
        GridSettings(db, ["run0"], ["ppo"], list(seeds), 20, 1, workers=1, job_fn=synthetic_job, display=False, **kw)
    )


def patch_store(monkeypatch: pytest.MonkeyPatch, fn) -> None:
    """Replace the store of a finished job where the driver looks it up."""
    monkeypatch.setattr(driver, "store_result", fn)


def operational(message: str) -> OperationalError:
    return OperationalError("UPDATE jobs SET ...", {}, sqlite3.OperationalError(message))


# --------------------------------------------------------------------------- disk full, I/O error
@pytest.mark.parametrize("message", ["database or disk is full", "disk I/O error"])
def test_disk_full_while_storing_stops_with_one_line_and_the_next_run_resumes(
    regimes, tmp_path, monkeypatch, message
) -> None:
    db = tmp_path / "r.db"

    def full(*args, **kw):
        raise operational(message)

    patch_store(monkeypatch, full)
    with pytest.raises(StoreError) as info:
        grid(db)
    line = str(info.value)
    assert "\n" not in line and message in line and "released" in line and "next run resumes" in line, line
    # nothing half-written, no job left running, no failure counted
    assert sql(db, "SELECT count(*) FROM episodes") == [(0,)]
    assert sql(db, "SELECT count(*) FROM jobs WHERE status IN ('running', 'failed') OR owner IS NOT NULL") == [(0,)]
    monkeypatch.undo()
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(regimes))
    summary = grid(db)
    assert (summary.done, summary.failed, summary.exit_code) == (2, 0, 0)
    assert sql(db, "SELECT status, failures FROM jobs") == [("done", 0), ("done", 0)]


def test_disk_full_that_refuses_every_write_leaves_the_jobs_to_the_stale_rule(regimes, tmp_path, monkeypatch) -> None:
    db = tmp_path / "r.db"

    def full(*args, **kw):
        raise operational("database or disk is full")

    patch_store(monkeypatch, full)
    monkeypatch.setattr(driver, "store_failure", full)
    monkeypatch.setattr(driver, "release_jobs", full)
    with pytest.raises(StoreError) as info:
        grid(db, seeds=(0,))
    line = str(info.value)
    assert "\n" not in line and "could not be released" in line and "heartbeat" in line, line
    assert sql(db, "SELECT status FROM jobs") == [("running",)]  # the next run takes it over once stale


def test_disk_full_through_the_cli_is_one_line_exit_2(regimes, tmp_path, monkeypatch) -> None:
    db = tmp_path / "r.db"
    monkeypatch.setenv("NUTRIBENCH_JOB", "fake")

    def full(*args, **kw):
        raise operational("database or disk is full")

    patch_store(monkeypatch, full)
    res = CliRunner().invoke(
        app,
        run_cli_args(db, "--workers", "1"),
    )
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and "database or disk is full" in res.output
    assert sql(db, "SELECT status FROM jobs") == [("interrupted",)]


# --------------------------------------------------------------------------- read-only database
def test_readonly_database_is_one_line_exit_2_and_nothing_is_lost(regimes, tmp_path, monkeypatch) -> None:
    """An immutable file (chattr +i; chmod 444 where not root): SQLite refuses the first write
    of the run, the claim, with "attempt to write a readonly database". Running as root makes
    chmod ineffective, so the claim's refusal is simulated."""
    db = tmp_path / "r.db"
    monkeypatch.setenv("NUTRIBENCH_JOB", "fake")
    args = run_cli_args(db, "--workers", "1", seeds=None)
    assert CliRunner().invoke(app, [*args, "--seeds", "0"]).exit_code == 0
    before = sql(db, "SELECT count(*) FROM episodes")

    def readonly(*a, **kw):
        raise operational("attempt to write a readonly database")

    monkeypatch.setattr(driver, "claim_jobs", readonly)
    res = CliRunner().invoke(app, [*args, "--seeds", "0,21"])
    assert res.exit_code == 2, res.output
    assert "Traceback" not in res.output and "readonly database" in res.output
    errors = [ln for ln in res.output.splitlines() if "readonly database" in ln]  # (not the tmp path's name)
    assert len(errors) == 1 and errors[0].startswith("error: cannot write to"), res.output
    assert sql(db, "SELECT count(*) FROM episodes") == before
    assert sql(db, "SELECT status FROM jobs ORDER BY seed") == [("done",), ("pending",)]
    monkeypatch.undo()
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(regimes))
    monkeypatch.setenv("NUTRIBENCH_JOB", "fake")
    assert CliRunner().invoke(app, [*args, "--seeds", "0,21"]).exit_code == 0
    assert sql(db, "SELECT status FROM jobs ORDER BY seed") == [("done",), ("done",)]


# --------------------------------------------------------------------------- write lock
def test_a_result_that_meets_the_write_lock_is_kept_and_stored_when_it_clears(regimes, tmp_path, monkeypatch) -> None:
    db = tmp_path / "r.db"
    monkeypatch.setattr(
        schema, "make_engine", lambda url, writer=False: make_engine(url, writer=writer, busy_timeout_ms=200)
    )
    real = (
        driver.store_result
        if hasattr(driver, "store_result")
        else __import__("nutribench.scheduler.lifecycle").scheduler.lifecycle.store_result
    )
    holding, blocker = threading.Event(), []

    def hold_lock() -> None:
        con = sqlite3.connect(db, isolation_level=None)
        con.execute("BEGIN IMMEDIATE")
        holding.set()
        threading.Event().wait(1.5)
        con.execute("COMMIT")
        con.close()

    calls = []

    def locked_store(*args, **kw):
        calls.append(1)
        if not blocker:  # the first store meets a write transaction held by another connection
            blocker.append(threading.Thread(target=hold_lock))
            blocker[0].start()
            holding.wait(5)
        return real(*args, **kw)

    patch_store(monkeypatch, locked_store)
    summary = grid(db, seeds=(0,))
    blocker[0].join()
    assert (summary.done, summary.failed, summary.exit_code) == (1, 0, 0)
    assert sql(db, "SELECT status, failures, owner FROM jobs") == [("done", 0, None)]
    assert sql(db, "SELECT count(*) > 0 FROM episodes") == [(1,)]
    assert len(calls) >= 2  # met the lock, kept, stored again once it cleared


def test_a_result_still_locked_when_the_run_stops_is_named_in_one_line(regimes, tmp_path, monkeypatch) -> None:
    db = tmp_path / "r.db"
    monkeypatch.setenv("NUTRIBENCH_JOB", "fake")
    calls = []

    def locked_then_ctrl_c(*args, **kw):
        calls.append(1)
        if len(calls) == 1:
            raise operational("database is locked")
        raise KeyboardInterrupt  # Ctrl-C while the result waits for the lock

    patch_store(monkeypatch, locked_then_ctrl_c)
    res = CliRunner().invoke(
        app,
        run_cli_args(db, "--workers", "1"),
    )
    assert res.exit_code == 130, res.output
    lines = [ln for ln in res.output.splitlines() if "could not be stored" in ln]
    assert len(lines) == 1 and "run0" in lines[0] and "ppo" in lines[0], res.output
    assert sql(db, "SELECT status, failures FROM jobs") == [("interrupted", 0)]


# --------------------------------------------------------------------------- printed commands
def test_printed_commands_use_an_environment_variable_not_the_password() -> None:
    url = make_url(f"postgresql+psycopg://bench:{SECRET}@db.example/results")
    cmd = schema._upgrade_cmd(url)
    assert SECRET not in cmd and "***" not in cmd
    assert 'nutribench run --upgrade-only --db "$NUTRIBENCH_DB"' in cmd and "NUTRIBENCH_DB set to" in cmd
    plain = schema._upgrade_cmd(make_url("postgresql+psycopg://bench@db.example/results"))
    assert "--db postgresql+psycopg://bench@db.example/results" in plain


def test_report_hint_shows_no_password(monkeypatch) -> None:
    import nutribench.store as store_pkg
    from nutribench.report.data import ReportError, read_metrics

    url = make_url(f"postgresql+psycopg://bench:{SECRET}@db.example/results")

    class FakeStore(store_pkg.Store):  # the real one's `with` (disposed of at the end)
        display, engine = url.render_as_string(hide_password=True), None

        def __init__(self):
            self.url = url

        def dispose(self):
            pass

    monkeypatch.setattr(store_pkg, "open_store", lambda db: FakeStore())
    monkeypatch.setattr(store_pkg, "read_episode_metrics", lambda engine, phase=None: pd.DataFrame())
    with pytest.raises(ReportError) as info:
        read_metrics(url.render_as_string(hide_password=False))
    assert SECRET not in str(info.value) and '--db "$NUTRIBENCH_DB"' in str(info.value)
    # the leaderboard reads through the same reader: its hint used to paste the URL as given
    from nutribench.report.leaderboard import leaderboard_from_db

    with pytest.raises(ReportError) as info:
        leaderboard_from_db(url.render_as_string(hide_password=False))
    assert SECRET not in str(info.value) and "holds no evaluation days yet" in str(info.value)


def test_the_db_option_reads_nutribench_db(tmp_path, monkeypatch) -> None:
    where = tmp_path / "elsewhere.db"
    monkeypatch.setenv("NUTRIBENCH_DB", str(where))
    res = CliRunner().invoke(app, ["status"])
    assert res.exit_code == 2 and str(where) in res.output.replace("\n", ""), res.output


# --------------------------------------------------------------------------- every secret a URL holds (issue 52)
@pytest.mark.parametrize(
    ("given", "shown"),
    [
        (f"postgresql://lab:p@ss@{SECRET}@localhost/db", "postgresql://lab:***@localhost/db"),
        (f"postgresql://lab:p%40ss%40{SECRET}@localhost/db", "postgresql://lab:***@localhost/db"),
        (
            f"postgresql://localhost/db?password={SECRET}&sslmode=require",
            "postgresql://localhost/db?password=***&sslmode=require",
        ),
        (
            f"postgresql+psycopg://lab@h:5432/db?sslpassword={SECRET}&passfile={SECRET}&connect_timeout=3",
            "postgresql+psycopg://lab@h:5432/db?connect_timeout=3&passfile=***&sslpassword=***",
        ),
        (f"postgresql://h/db?sslkey={SECRET}&access_token={SECRET}", "postgresql://h/db?access_token=***&sslkey=***"),
        (
            f"postgresql://lab:{SECRET}@/db?host=/tmp&client_secret={SECRET}",
            "postgresql://lab:***@/db?client_secret=***&host=%2Ftmp",
        ),
    ],
)
def test_a_url_is_shown_without_any_of_its_secrets(given: str, shown: str) -> None:
    """A password as ``?password=`` was printed as is, and an unencoded ``@`` in one showed its
    end (``lab:***@ss@SECRET@...``): the host starts after the last ``@``, and every query
    parameter named like a secret is hidden, wherever the URL is shown."""
    from nutribench.store.engine import database_url, display_url, hide_secrets

    url = database_url(given)
    assert display_url(url) == shown
    assert SECRET not in hide_secrets(given) and hide_secrets(given).count("***") == shown.count("***")  # as given
    assert url.host in (None, "localhost", "h")  # the driver is given the host, not a part of the password
    cmd = schema.db_command("nutribench status", url)
    assert SECRET not in cmd and '--db "$NUTRIBENCH_DB"' in cmd


def test_an_unencoded_at_belongs_to_the_password() -> None:
    from nutribench.store.engine import database_url

    url = database_url(f"postgresql+psycopg://lab:p@ss@{SECRET}@localhost:5433/db")
    assert (url.username, url.password, url.host, url.port) == ("lab", f"p@ss@{SECRET}", "localhost", 5433)
    url = database_url("postgresql://me@corp@localhost/db")  # no password: the user name holds it
    assert (url.username, url.password, url.host) == ("me@corp", None, "localhost")
    plain = schema.db_command("nutribench status", database_url("postgresql://lab@h/db?sslmode=require"))
    assert "--db 'postgresql://lab@h/db?sslmode=require'" in plain  # nothing secret: as given, to paste


@pytest.mark.parametrize(
    ("command", "url"),
    [
        (["status"], f"postgresql+psycopg://lab:p@ss@{SECRET}@127.0.0.1:1/db?password={SECRET}&connect_timeout=2"),
        (["status"], f"postgresql://lab:p@ss@{SECRET}@localhost:notaport/db?password={SECRET}"),
        (["status"], f"postgresql+nope://lab:p@ss@{SECRET}@localhost/db?sslpassword={SECRET}"),
        (["run", "--regimes", "run0", "--algos", "ppo"], f"sqlite:///:memory:?password={SECRET}"),
    ],
)
def test_an_error_about_a_url_shows_none_of_its_secrets(command, url) -> None:
    """The refused URL (unparsable, unknown driver, nobody listening, in memory) in one line,
    its secrets hidden."""
    res = CliRunner().invoke(app, [*command, "--db", url])
    assert res.exit_code == 2 and res.output.startswith("error:"), res.output
    assert SECRET not in res.output and "***" in res.output and "Traceback" not in res.output, res.output


def test_an_error_line_hides_the_secrets_of_any_url_in_it(capsys) -> None:
    """The last line of defence: a message that formats a ``--db`` URL as given (one place
    might) is printed without its secrets."""
    from nutribench.cli.common import print_error

    print_error(
        f"x holds no evaluation days yet: `nutribench run --db postgresql://lab:p@ss@{SECRET}@h/db?token={SECRET}`"
    )
    err = capsys.readouterr().err
    assert SECRET not in err and "postgresql://lab:***@h/db?token=***" in err, err
