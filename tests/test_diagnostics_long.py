"""Training diagnostics as a long table (schema revision 0007: one row per job, update and
quantity): the migration carries every value of a revision-0006 database (and back), a
plug-in's own quantity is stored, read and archived without a schema change, and the
committed archives (one row per update) read into the long table and back unchanged."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from alembic import command
from sqlalchemy import create_engine, text
from sqlalchemy.orm import Session
from typer.testing import CliRunner

from nutribench import diagnostics as d
from nutribench.cli import app
from nutribench.scheduler.grid import Grid
from nutribench.scheduler.lifecycle import claim_jobs, store_result
from nutribench.scheduler.registration import load_grid_configs, register_grid
from nutribench.scheduler.worker import JobResult
from nutribench.store import head_revision, make_engine, open_store, read_training_diagnostics
from nutribench.store.archive.export import wide_diagnostics
from nutribench.store.archive.format import columns
from nutribench.store.archive.merge import database_rows
from nutribench.store.engine import database_url
from nutribench.store.models import DIAGNOSTIC_VALUES_COLUMNS, TRAINING_DIAGNOSTICS_COLUMNS, Base
from nutribench.store.schema import alembic_config, upgrade_connection

REPO = Path(__file__).resolve().parents[1]
#: a committed archive with diagnostics (the batched engine's PPO, 20 jobs, 10,000 updates)
ARCHIVE = REPO / "reports" / "tuned_v2" / "data" / "part3_ppo_tuned_v2.npz"


def sql(db: Path, query: str) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return con.execute(query).fetchall()
    finally:
        con.close()


# --------------------------------------------------------------------------- the migration
def _wide_rows(rng: np.random.Generator, n: int) -> list[tuple]:
    """``n`` rows of the wide table (update, timestep, the 13 quantities), about a third NULL,
    values over many magnitudes, one row with every quantity NULL."""
    rows = []
    for u in range(n):
        values = rng.standard_normal(len(d.QUANTITIES)) * 10.0 ** rng.integers(-300, 300, len(d.QUANTITIES))
        null = rng.random(len(d.QUANTITIES)) < 0.35 if u else np.ones(len(d.QUANTITIES), dtype=bool)
        rows.append((u, 50 * (u + 1) + 250_000, *(None if z else float(v) for v, z in zip(values, null))))
    return rows


def _rows(url: str, query: str) -> list[tuple]:
    engine = make_engine(url)
    try:
        with engine.connect() as conn:
            return [tuple(r) for r in conn.execute(text(query))]
    finally:
        engine.dispose()


def check_the_0007_migration(url: str) -> None:
    """A revision-0006 database at ``url`` with 162 wide rows (three jobs, one a dry run's)
    upgraded to the head and downgraded again: every value kept, both ways."""
    engine = make_engine(url, writer=True)
    rng = np.random.default_rng(7)
    names = ("job_id", *d.COLUMNS)
    cols = ", ".join(f'"{c}"' for c in names)
    marks = ", ".join(f":p{i}" for i in range(len(names)))
    with engine.begin() as conn:
        upgrade_connection(conn, "0006")
        conn.execute(text("INSERT INTO regimes VALUES (1, 'run0', 1, 'aa', '{}', NULL, '2026-01-01')"))
        conn.execute(text("INSERT INTO agent_configs VALUES (1, 'ppo', 'ppo', 1, 'bb', '{}', NULL, '2026-01-01')"))
        for job, seed, fake in ((1, 0, "false"), (2, 1, "false"), (3, 2, "true")):
            conn.execute(
                text(
                    "INSERT INTO jobs (id, regime_id, agent_config_id, seed, episodes, eval_episodes, status, attempt, "
                    f"failures, episodes_done, created_at, fake, engine) "
                    f"VALUES ({job}, 1, 1, {seed}, 2, 0, 'done', 1, 0, 2, '2026-01-01', {fake}, 'sb3')"
                )
            )
        for job, n in ((1, 120), (2, 37), (3, 5)):
            rows = [dict(zip([f"p{i}" for i in range(len(names))], (job, *r))) for r in _wide_rows(rng, n)]
            conn.execute(text(f"INSERT INTO diagnostics ({cols}) VALUES ({marks})"), rows)
    engine.dispose()
    table = _rows(url, f'SELECT {cols} FROM diagnostics ORDER BY job_id, "update"')
    view = _rows(url, 'SELECT * FROM training_diagnostics ORDER BY job_id, "update"')
    assert len(table) == 162 and len(view) == 157  # the dry run's job is in the table, not the view
    filled = sum(v is not None for row in table for v in row[3:])

    res = CliRunner().invoke(app, ["run", "--upgrade-only", "--db", url])
    assert res.exit_code == 0 and "upgraded from 0006" in " ".join(res.output.split()), res.output
    assert _rows(url, "SELECT version_num FROM nutribench_alembic_version") == [(head_revision(),)]
    # every value kept, exactly: the view reads as it did (same columns, same rows), and the
    # long table holds a timestep per update and a row per non-NULL value, nothing else
    assert _rows(url, 'SELECT * FROM training_diagnostics ORDER BY job_id, "update"') == view
    assert _rows(url, "SELECT count(*) FROM diagnostics") == [(len(table) + filled,)]
    long = {(j, u, n): v for j, u, n, v in _rows(url, 'SELECT job_id, "update", name, value FROM diagnostics')}
    for row in table:
        job, update, timestep = row[:3]
        assert long[(job, update, "timestep")] == timestep
        for q, v in zip(d.QUANTITIES, row[3:]):
            assert long.get((job, update, q)) == v
    df = read_training_diagnostics(url)
    assert tuple(df.columns) == TRAINING_DIAGNOSTICS_COLUMNS and len(df) == len(view)
    assert df["timestep"].dtype.kind == "i"
    values = read_sql_columns(url, "diagnostic_values")
    assert values == DIAGNOSTIC_VALUES_COLUMNS

    # and back: the wide table as it was
    engine = make_engine(url, writer=True)
    with engine.begin() as conn:
        cfg = alembic_config()
        cfg.attributes["connection"] = conn
        command.downgrade(cfg, "0006")
    engine.dispose()
    assert _rows(url, f'SELECT {cols} FROM diagnostics ORDER BY job_id, "update"') == table
    assert _rows(url, 'SELECT * FROM training_diagnostics ORDER BY job_id, "update"') == view


def read_sql_columns(url: str, view: str) -> tuple[str, ...]:
    engine = make_engine(url)
    try:
        with engine.connect() as conn:
            return tuple(conn.execute(text(f"SELECT * FROM {view} WHERE 1 = 0")).keys())
    finally:
        engine.dispose()


def test_the_migration_carries_every_value_of_a_0006_database_and_back(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    check_the_0007_migration(str(database_url(db)))
    assert "diagnostic_values" not in {r[0] for r in sql(db, "SELECT name FROM sqlite_master")}  # downgraded


@pytest.mark.slow
@pytest.mark.serial
def test_the_migration_carries_every_value_on_postgres(pg_url: str) -> None:
    check_the_0007_migration(pg_url)


# --------------------------------------------------------------------------- a plug-in's name
def _running_job(db: Path) -> tuple[object, int]:
    grid = Grid(("run0",), ("ppo",), (0,), 2, 0)
    regimes, agents = load_grid_configs(grid)
    store = open_store(db, writer=True)
    (job_id,) = register_grid(store, grid, regimes, agents)
    claim_jobs(store, [job_id], set(), 1, "me")
    return store, job_id


def _result(job_id: int, diagnostics: list[dict]) -> JobResult:
    day = dict(foods=3, final_distance=0.5, overshoot_ratio=0.1, final_C=1.0, final_F=1.0, final_P=1.0)
    train = [{"episode": k, "return": -1.0, **day, "first_overshoot_step": None, "entropy": 0.6} for k in range(2)]
    return JobResult(job_id, train, [], [], {}, diagnostics=diagnostics)


def test_a_plugins_own_quantity_is_stored_read_and_archived_without_a_schema_change(tmp_path: Path) -> None:
    db = tmp_path / "p.db"
    store, job_id = _running_job(db)
    schema = sql(db, "SELECT type, name, sql FROM sqlite_master ORDER BY name")
    rows = [
        {"update": u, "timestep": 500 * (u + 1), "value_loss": 1.0 / (u + 1), "trust_region": 0.25 * u, "kl_beta": 3.0}
        for u in range(4)
    ]
    rows[2]["kl_beta"] = float("nan")  # not finite: no value, as for a built-in quantity
    assert store_result(store, _result(job_id, rows), "me", None)
    store.dispose()
    assert sql(db, "SELECT type, name, sql FROM sqlite_master ORDER BY name") == schema  # no schema change
    assert sql(db, "SELECT version_num FROM nutribench_alembic_version") == [(head_revision(),)]
    assert sql(db, "SELECT count(*) FROM diagnostic_values WHERE name = 'trust_region'") == [(4,)]

    df = read_training_diagnostics(db)
    assert tuple(df.columns) == (*TRAINING_DIAGNOSTICS_COLUMNS[:-1], "kl_beta", "trust_region", "job_id")
    assert df["trust_region"].tolist() == [0.0, 0.25, 0.5, 0.75]
    assert df["kl_beta"].isna().tolist() == [False, False, True, False]
    assert df["value_loss"].tolist() == [1.0, 0.5, 1 / 3, 0.25] and df["policy_loss"].isna().all()
    # the view keeps its columns; the report's reader is the same function
    assert len(sql(db, "SELECT * FROM training_diagnostics")) == 4

    # an archive carries it as one more column, and an import stores it again
    archive, dst = tmp_path / "a.npz", tmp_path / "b.db"
    res = CliRunner().invoke(app, ["db", "export", "--db", str(db), str(archive)])
    assert res.exit_code == 0 and "4 training diagnostics rows" in res.output, res.output
    with np.load(archive) as z:
        assert z["diagnostics.trust_region"].tolist() == [0.0, 0.25, 0.5, 0.75]
        assert z["diagnostics.kl_beta.null"].tolist() == [False, False, True, False]
    res = CliRunner().invoke(app, ["db", "import", str(archive), "--db", str(dst)])
    assert res.exit_code == 0, res.output
    pd.testing.assert_frame_equal(read_training_diagnostics(dst), df)


def test_a_plugins_own_quantity_is_written_to_tensorboard_too(tmp_path: Path) -> None:
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    from nutribench.scheduler.batched_job import write_tensorboard

    rows = [{"update": u, "timestep": 500 * (u + 1), "value_loss": 1.0, "trust_region": 0.25 * u} for u in range(3)]
    write_tensorboard(tmp_path / "tb", rows)
    acc = EventAccumulator(str(tmp_path / "tb"))
    acc.Reload()
    assert set(acc.Tags()["scalars"]) == {"diagnostics/value_loss", "diagnostics/trust_region"}
    events = acc.Scalars("diagnostics/trust_region")
    assert [(e.step, e.value) for e in events] == [(500, 0.0), (1000, 0.25), (1500, 0.5)]


def test_a_name_that_is_no_quantitys_fails_the_store_and_writes_nothing(tmp_path: Path) -> None:
    db = tmp_path / "p.db"
    store, job_id = _running_job(db)
    bad = [{"update": 0, "timestep": 500, "train/loss": 1.0}]
    with pytest.raises(ValueError, match="'train/loss' is not a quantity's name"):
        store_result(store, _result(job_id, bad), "me", None)
    store.dispose()
    assert sql(db, "SELECT count(*) FROM diagnostics") == sql(db, "SELECT count(*) FROM episodes") == [(0,)]
    assert [d.valid_name(n) for n in ("q_mean", "x" * 64, "x" * 65, "update", "Loss", "")] == [
        True,
        True,
        False,
        False,
        False,
        False,
    ]


def test_an_archive_with_another_diagnostics_array_is_refused(tmp_path: Path) -> None:
    """A name that is no quantity's is not part of the format (an archive's names are checked)."""
    db = tmp_path / "p.db"
    store, job_id = _running_job(db)
    assert store_result(store, _result(job_id, [{"update": 0, "timestep": 500, "value_loss": 1.0}]), "me", None)
    store.dispose()
    archive = tmp_path / "a.npz"
    assert CliRunner().invoke(app, ["db", "export", "--db", str(db), str(archive)]).exit_code == 0
    with np.load(archive) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["diagnostics.Loss"] = np.ones(1)
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    res = CliRunner().invoke(app, ["db", "import", str(bad), "--db", str(tmp_path / "c.db")])
    assert res.exit_code == 2 and "array 'diagnostics.Loss' is not part of the format" in res.output, res.output
    assert not (tmp_path / "c.db").exists()


# --------------------------------------------------------------------------- committed archives
def _archive_frame(arrays: dict[str, np.ndarray], meta: dict) -> pd.DataFrame:
    """An archive's diagnostics as one row per update: regime, seed and the vocabulary's columns."""
    jobs = meta["jobs"]
    out = {
        "regime": [jobs[i]["regime"][0] for i in arrays["diagnostics.job"]],
        "seed": [jobs[i]["seed"] for i in arrays["diagnostics.job"]],
    }
    for c in d.COLUMNS:
        values = arrays[f"diagnostics.{c}"]
        null = arrays.get(f"diagnostics.{c}.null")
        out[c] = values if null is None else np.where(null, np.nan, values)
    return pd.DataFrame(out).sort_values(["regime", "seed", "update"], ignore_index=True)


def test_a_committed_archives_diagnostics_go_into_the_long_table_and_back_unchanged() -> None:
    """The rows of a committed archive (one per update) as the import writes them (long) and as
    an export reads them back (one per update): the same columns, every value equal."""
    with np.load(ARCHIVE) as z:
        arrays = {k: z[k] for k in z.files}
    engine = create_engine("sqlite://")
    Base.metadata.create_all(engine)
    positions = np.argsort(arrays["diagnostics.job"], kind="stable")
    bounds = np.searchsorted(arrays["diagnostics.job"][positions], np.arange(arrays["diagnostics.job"].max() + 2))
    with Session(engine) as s:
        n = 0
        for i in range(len(bounds) - 1):
            count, rows = database_rows("diagnostics", arrays, positions[bounds[i] : bounds[i + 1]], i + 1)
            n += count
            s.execute(Base.metadata.tables["diagnostics"].insert(), rows)
        assert n == len(arrays["diagnostics.job"]) == 10_000
        layout, back = wide_diagnostics(s, list(range(1, len(bounds))))
    assert [c.name for c in columns(layout)] == list(d.COLUMNS)
    got = np.array([[np.nan if v is None else v for v in r] for r in back], dtype=np.float64)
    order = np.lexsort((arrays["diagnostics.update"], arrays["diagnostics.job"]))
    assert np.array_equal(got[:, 0], arrays["diagnostics.job"][order] + 1)
    for k, c in enumerate(d.COLUMNS, start=1):
        want = arrays[f"diagnostics.{c}"][order].astype(np.float64)
        null = arrays.get(f"diagnostics.{c}.null")
        if null is not None:
            want = np.where(null[order], np.nan, want)
        assert np.array_equal(got[:, k], want, equal_nan=True), c


@pytest.mark.slow
def test_a_committed_archive_imports_with_the_same_diagnostics(tmp_path: Path) -> None:
    """``nutribench db import`` of a committed archive (about a minute: its evaluation days are
    replayed): the database reads back every diagnostics value the archive holds."""
    db = tmp_path / "c.db"
    res = CliRunner().invoke(app, ["db", "import", str(ARCHIVE), "--db", str(db)])
    assert res.exit_code == 0 and "10,000 training diagnostics rows" in res.output, res.output
    with np.load(ARCHIVE) as z:
        arrays = {k: z[k] for k in z.files}
    want = _archive_frame(arrays, json.loads(arrays["meta"].tobytes().decode()))
    got = read_training_diagnostics(db).sort_values(["regime", "seed", "update"], ignore_index=True)
    assert tuple(got.columns) == TRAINING_DIAGNOSTICS_COLUMNS
    got = got[list(want.columns)].astype(dict.fromkeys(d.QUANTITIES, "float64"))  # a column all NULL reads as None
    pd.testing.assert_frame_equal(got, want, check_dtype=False)
