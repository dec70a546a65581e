"""The results database: migrations (from empty and from 0001), models == migrations,
one-line errors for bad databases, and a reader beside a writer (WAL)."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
from alembic.autogenerate import compare_metadata
from alembic.runtime.migration import MigrationContext
from sqlalchemy import create_engine, inspect, text
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.store import Base, StoreError, head_revision, make_engine, open_store, read_episode_metrics
from nutribench.store.engine import database_url
from nutribench.store.models import EPISODE_METRICS_COLUMNS, EVAL_TRAJECTORY_COLUMNS, VIEWS
from nutribench.store.schema import VERSION_TABLE, revision_chain, upgrade_connection


def _include(obj, name, type_, reflected, compare_to) -> bool:
    return not (type_ == "table" and name in VIEWS)


def make_0001(db: Path) -> None:
    """A database at revision 0001 holding one finished job with two episodes."""
    engine = make_engine(database_url(db), writer=True)
    with engine.begin() as conn:
        upgrade_connection(conn, "0001")
        conn.execute(text("INSERT INTO regimes VALUES (1, 'run0', 1, 'aa', '{}', NULL, '2026-01-01')"))
        conn.execute(text("INSERT INTO agent_configs VALUES (1, 'ppo', 'ppo', 1, 'bb', '{}', NULL, '2026-01-01')"))
        conn.execute(
            text(
                "INSERT INTO jobs (id, regime_id, agent_config_id, seed, episodes, eval_episodes, status, attempt, failures, "
                "episodes_done, created_at) VALUES (1, 1, 1, 0, 2, 0, 'done', 1, 0, 2, '2026-01-01')"
            )
        )
        for k in range(2):
            conn.execute(text(f"INSERT INTO episodes VALUES (1, 'train', {k}, -1.5, 3, 0.5, 0.1, 1, 1, 1, NULL, 0.2)"))
    engine.dispose()


def test_revisions_are_linear() -> None:
    assert revision_chain() == ["0001", "0002", "0003", "0004", "0005", "0006", "0007"] and head_revision() == "0007"


def test_create_from_empty_matches_the_models(tmp_path: Path) -> None:
    store = open_store(tmp_path / "new.db", writer=True)
    assert (store.created, store.revision) == (True, head_revision())
    with store.engine.connect() as conn:
        names = set(inspect(conn).get_table_names())
        assert {"regimes", "agent_configs", "jobs", "episodes", "eval_steps", "diagnostics", VERSION_TABLE} <= names
        assert set(inspect(conn).get_view_names()) == set(VIEWS)
        diff = compare_metadata(
            MigrationContext.configure(
                conn, opts={"include_object": _include, "compare_type": True, "version_table": VERSION_TABLE}
            ),
            Base.metadata,
        )
        cols = [c[1] for c in conn.execute(text("PRAGMA table_info(episode_metrics)"))]
        assert tuple(cols) == EPISODE_METRICS_COLUMNS
        cols = [c[1] for c in conn.execute(text("PRAGMA table_info(eval_trajectories)"))]
        assert tuple(cols) == EVAL_TRAJECTORY_COLUMNS
        assert conn.execute(text("PRAGMA journal_mode")).scalar() == "wal"
    store.dispose()
    assert diff == []


def test_upgrade_from_0001_keeps_the_data(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    make_0001(db)
    with pytest.raises(
        StoreError, match=r"revision 0001, this nutribench needs 0007: run `nutribench run --upgrade-only"
    ):
        open_store(db)  # readers refuse, with the command that fixes it
    res = CliRunner().invoke(app, ["run", "--upgrade-only", "--db", str(db)])
    assert res.exit_code == 0 and "upgraded from 0001" in res.output, res.output
    store = open_store(db)
    with store.engine.connect() as conn:
        diff = compare_metadata(
            MigrationContext.configure(
                conn, opts={"include_object": _include, "compare_type": True, "version_table": VERSION_TABLE}
            ),
            Base.metadata,
        )
        assert conn.execute(text("SELECT count(*) FROM eval_steps")).scalar() == 0
    store.dispose()
    assert diff == []
    df = read_episode_metrics(db)
    assert list(df["episode"]) == [0, 1] and set(df["regime"]) == {"run0"} and set(df["algo"]) == {"ppo"}
    again = open_store(db, writer=True)  # at head: nothing to do
    assert (again.upgraded_from, again.created) == (None, False)
    again.dispose()


def test_bad_databases_are_one_line_errors(tmp_path: Path) -> None:
    text_file = tmp_path / "notes.txt"
    text_file.write_text("hello\n")
    foreign = tmp_path / "foreign.db"
    e = create_engine(f"sqlite:///{foreign}")
    with e.begin() as conn:
        conn.execute(text("CREATE TABLE customers (id INTEGER)"))
    e.dispose()
    newer = tmp_path / "newer.db"
    open_store(newer, writer=True).dispose()
    e = create_engine(f"sqlite:///{newer}")
    with e.begin() as conn:
        conn.execute(text("UPDATE nutribench_alembic_version SET version_num = '0099'"))
    e.dispose()
    cases = [
        (dict(db=text_file, writer=True), "is not a SQLite database"),
        (dict(db=tmp_path, writer=True), "is a directory"),
        (dict(db=tmp_path / "no" / "x.db", writer=True), "does not exist"),
        (dict(db=tmp_path / "absent.db"), "no results database"),
        (dict(db=foreign, writer=True), "holds tables (customers...) but no nutribench schema"),
        (dict(db=newer, writer=True), "unknown to this nutribench"),
        (dict(db="postgresql+nope://u@h/x"), "cannot use this database URL"),
        (
            dict(db="postgresql+psycopg://u:secret@127.0.0.1:1/x"),
            "u:***@127.0.0.1:1/x: connection failed",
        ),  # nobody listens
        (dict(db="://x"), "not a valid SQLAlchemy URL"),
    ]
    for kwargs, message in cases:
        with pytest.raises(StoreError) as err:
            open_store(**kwargs)
        assert message in str(err.value) and "\n" not in str(err.value), str(err.value)
    assert text_file.read_text() == "hello\n"
    assert not (tmp_path / "absent.db").exists()


def test_a_reader_does_not_wait_for_a_writer(tmp_path: Path) -> None:
    db = tmp_path / "wal.db"
    make_0001(db)
    writer = open_store(db, writer=True)
    reader = open_store(db)
    try:
        with writer.engine.connect() as w:
            w.begin()  # BEGIN IMMEDIATE: holds the write lock until the end of this block
            w.execute(text("UPDATE jobs SET status = 'failed' WHERE id = 1"))
            with reader.engine.connect() as r:
                r.exec_driver_sql(
                    "PRAGMA busy_timeout = 0"
                )  # a reader that had to wait would fail: "database is locked"
                assert r.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
                assert r.execute(text("SELECT status FROM jobs WHERE id = 1")).scalar() == "done"
            w.commit()
        with reader.engine.connect() as r:
            assert r.execute(text("SELECT status FROM jobs WHERE id = 1")).scalar() == "failed"
    finally:
        writer.dispose()
        reader.dispose()


def test_a_worker_does_not_import_the_database_layer():
    """A worker process imports neither SQLAlchemy nor alembic (the single job once imported
    store.engine for a timestamp)."""
    import subprocess
    import sys

    code = "import sys, nutribench.scheduler.single_job, nutribench.scheduler.synthetic; print(sorted(m for m in ('sqlalchemy', 'alembic') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out == "[]"


def test_a_writer_opening_a_new_database_waits_for_a_lock_held_elsewhere(tmp_path):
    """Two drivers started at the same moment on a new file: one would fail with "database
    is locked" at open (SQLite does not call the busy handler when switching
    to WAL). Another connection holds the lock for 0.5 s: the open now waits for it."""
    import sqlite3
    import threading

    path = tmp_path / "new.db"
    holder = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
    holder.execute("BEGIN IMMEDIATE")
    holder.execute("PRAGMA user_version = 0")  # a write: the holder now has the lock
    release = threading.Timer(0.5, lambda: holder.execute("ROLLBACK"))
    release.start()
    try:
        store = open_store(path, writer=True)
    finally:
        release.join()
        holder.close()
    assert store.created
    with store.engine.connect() as conn:
        assert conn.exec_driver_sql("PRAGMA journal_mode").scalar() == "wal"
    store.dispose()


#: issue 74: every command that opens the database, on one whose version table holds two rows
TWO_HEADS_COMMANDS = [
    ["status"],
    ["run", "--regimes", "run0", "--algos", "mc", "--seeds", "0", "--days", "1"],
    ["run", "--upgrade-only"],
    ["report", "--table", "results", "--out", "rep"],
    ["tune", "--study", "s", "--space", "ppo", "--trials", "1"],
    ["tune", "status", "--study", "s"],
    ["tune", "best", "--study", "s"],
    ["db", "import", "real.npz"],
    ["db", "export", "out.npz"],
    ["leaderboard", "--reps", "100"],
]


@pytest.fixture(scope="module")
def two_heads(tmp_path_factory) -> Path:
    """A recorded database and its archive; a second row, a revision from nowhere, in the version table."""
    from tests.recorded import recorded_archive

    folder = tmp_path_factory.mktemp("two-heads")
    db, _ = recorded_archive(folder)
    e = create_engine(f"sqlite:///{db}")
    with e.begin() as conn:
        conn.execute(text(f"INSERT INTO {VERSION_TABLE} VALUES ('zzzz9999future')"))
    e.dispose()
    return folder


@pytest.mark.parametrize("args", TWO_HEADS_COMMANDS, ids=[" ".join(a[:2]) for a in TWO_HEADS_COMMANDS])
def test_two_rows_in_the_version_table_are_one_line(two_heads: Path, args, monkeypatch) -> None:
    """Two revisions in ``nutribench_alembic_version``: one line naming the table and what to do (it
    was alembic's 84-line "more than one head present" traceback), nothing written."""
    from tests.conftest import one_error_line

    monkeypatch.chdir(two_heads)
    monkeypatch.setenv("NUTRIBENCH_JOB", "fake")
    monkeypatch.setenv("NUTRIBENCH_DB", "real.db")
    res = CliRunner().invoke(app, args)
    starts = args[:2] in (["run", "--regimes"], ["tune", "--study"])  # their line saying what they start comes first
    if starts:
        start, _, rest = res.output.partition("\n")
        assert start.startswith(("nutribench run: ", "tune s: ")), res.output
        res = SimpleNamespace(exit_code=res.exit_code, output=rest)
    line = one_error_line(res)
    assert f"version table {VERSION_TABLE} holds 2 revisions ({head_revision()}, zzzz9999future)" in line, line
    assert "delete the rows that are not the database's schema revision" in line, line
    e = create_engine(f"sqlite:///{two_heads / 'real.db'}")
    with e.connect() as conn:
        assert conn.execute(text(f"SELECT count(*) FROM {VERSION_TABLE}")).scalar() == 2
        assert conn.execute(text("SELECT count(*) FROM jobs")).scalar() == 2
    e.dispose()
    assert not (two_heads / "out.npz").exists() and not (two_heads / "rep").exists()


def test_two_of_nutribenchs_revisions_in_the_old_version_table_are_one_line(tmp_path: Path) -> None:
    """A database from before the move (its revision in ``alembic_version``) holding two of
    nutribench's revisions there: refused the same way, naming that table."""
    db = tmp_path / "legacy.db"
    make_0001(db)
    e = create_engine(f"sqlite:///{db}")
    with e.begin() as conn:
        conn.execute(text(f"ALTER TABLE {VERSION_TABLE} RENAME TO alembic_version"))
        conn.execute(text("INSERT INTO alembic_version VALUES ('0002')"))
    e.dispose()
    for writer in (False, True):
        with pytest.raises(StoreError, match=r"version table alembic_version holds 2 revisions \(0001, 0002\)"):
            open_store(db, writer=writer)
