"""Evaluation during training in the results database: ``nutribench run --eval-every`` (both
engines) stores one row per validation day in ``validation_episodes`` with the job's other
rows (in its one transaction), the ``learning_curve`` view reads it, a run without the option stores none, and
revision 0006 upgrades a revision-0005 database that holds data."""

from __future__ import annotations

import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from sqlalchemy import text
from typer.testing import CliRunner

from nutribench.agents.api import validation_food_streams
from nutribench.baselines import day_yardsticks, gap_closed, validation_yardsticks
from nutribench.cli import app
from nutribench.scheduler.grid import Grid
from nutribench.scheduler.lifecycle import claim_jobs, store_result
from nutribench.scheduler.registration import load_grid_configs, register_grid
from nutribench.scheduler.worker import JobResult
from nutribench.store import make_engine, open_store, read_episode_metrics, read_learning_curve
from nutribench.store.engine import database_url
from nutribench.store.models import LEARNING_CURVE_COLUMNS
from nutribench.store.schema import upgrade_connection

REPO = Path(__file__).resolve().parents[1]


def sql(db: Path, query: str) -> list[tuple]:
    con = sqlite3.connect(db)
    try:
        return con.execute(query).fetchall()
    finally:
        con.close()


def _run(db: Path, *extra: str) -> None:
    args = ["run", "--regimes", "run3", "--algos", "mc", "--seeds", "0,1", "--episodes", "4", "--db", str(db)]
    res = CliRunner().invoke(app, [*args, "--workers", "1", *extra])
    assert res.exit_code == 0, res.output


def _running_job(db: Path) -> tuple[object, int]:
    grid = Grid(("run0",), ("ppo",), (0,), 4, 0)
    regimes, agents = load_grid_configs(grid)
    store = open_store(db, writer=True)
    (job_id,) = register_grid(store, grid, regimes, agents)
    claim_jobs(store, [job_id], set(), 1, "me")
    return store, job_id


def _day(train_day: int, episode: int, ret: float) -> dict:
    metrics = dict(foods=3, final_distance=0.5, overshoot_ratio=0.1, final_C=1.0, final_F=1.0, final_P=1.0)
    extra = dict(first_overshoot_step=None, entropy=None, never=-2.0, planner=2.0)
    return {"train_day": train_day, "episode": episode, "return": ret, **metrics, **extra}


def test_the_rows_are_written_in_the_job_transaction(tmp_path: Path) -> None:
    db = tmp_path / "t.db"
    store, job_id = _running_job(db)
    rows = [_day(2, 0, -1.0), _day(2, 1, 0.0), _day(4, 0, 1.0), _day(4, 1, 2.0)]
    bad = JobResult(job_id, [], [], [], {}, validation=[*rows, rows[0]])  # a day twice: the key refuses it
    with pytest.raises(Exception, match="UNIQUE"):
        store_result(store, bad, "me", None)
    assert sql(db, "SELECT count(*) FROM validation_episodes") == [(0,)]
    assert sql(db, f"SELECT status FROM jobs WHERE id = {job_id}") == [("running",)]
    assert store_result(store, JobResult(job_id, [], [], [], {}, validation=rows), "me", None)
    store.dispose()
    df = read_learning_curve(db)
    assert list(zip(df["train_day"], df["episode"], df["gap_closed"])) == [
        (2, 0, 0.25),
        (2, 1, 0.5),
        (4, 0, 0.75),
        (4, 1, 1.0),
    ]
    assert set(df["regime"]) == {"run0"} and set(df["algo"]) == {"ppo"}


def test_archives_carry_the_validation_days(tmp_path: Path) -> None:
    """``db export`` / ``db import`` carry the rows; a bad row in an archive is one line."""
    from nutribench.store.archive import export_results, import_results, verify_archive

    db = tmp_path / "t.db"
    store, job_id = _running_job(db)
    train = [
        {k: v for k, v in _day(0, e, -1.0).items() if k not in ("train_day", "never", "planner")} for e in range(4)
    ]
    rows = [_day(2, 0, -1.0), _day(2, 1, 0.0), _day(4, 0, 1.0)]
    assert store_result(store, JobResult(job_id, train, [], [], {}, validation=rows), "me", None)
    store.dispose()
    out = tmp_path / "a.npz"
    assert export_results(db, out)["validation_episodes"] == 3
    assert verify_archive(out)["validation_episodes"] == 3
    counts = import_results(out, tmp_path / "b.db")
    assert counts["validation_episodes"] == 3
    cols = ["regime", "algo", "seed", "train_day", "episode", "return", "never", "planner", "gap_closed"]
    assert read_learning_curve(tmp_path / "b.db")[cols].equals(read_learning_curve(db)[cols])
    arrays = dict(np.load(out))
    arrays["validation_episodes.train_day"] = np.array([2, 2, 2])  # day 0 after training day 2 twice
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    res = CliRunner().invoke(app, ["db", "import", str(bad), "--db", str(tmp_path / "c.db")])
    assert res.exit_code == 2 and "validation_episodes row" in res.output and "twice" in res.output, res.output
    assert not (tmp_path / "c.db").exists()


@pytest.mark.slow
@pytest.mark.parametrize("engine", ["sb3", "batched"])
def test_run_stores_the_learning_curve(tmp_path: Path, monkeypatch, engine: str) -> None:
    monkeypatch.delenv("NUTRIBENCH_DB", raising=False)
    db = tmp_path / "r.db"
    _run(db, "--engine", engine, "--eval-every", "2", "--val-episodes", "3")
    df = read_learning_curve(db)
    assert tuple(df.columns) == LEARNING_CURVE_COLUMNS
    assert len(df) == 2 * 2 * 3 and set(df["engine"]) == {engine}
    assert sorted(set(zip(df["seed"], df["train_day"]))) == [(0, 2), (0, 4), (1, 2), (1, 4)]
    for seed, rows in df.groupby("seed"):
        yard = day_yardsticks("run3", validation_food_streams("run3", int(seed), 3))
        assert list(rows["never"][:3]) == [y["never"] for y in yard]
        assert list(rows["planner"][:3]) == [y["planner"] for y in yard]
        means = validation_yardsticks("run3", int(seed), 3)
        assert means["never"] == pytest.approx(rows["never"][:3].mean())
    row = df.iloc[0]
    assert row["gap_closed"] == pytest.approx(gap_closed(row["return"], row["never"], row["planner"]))
    # the test days' rows are those of a run without the evaluation
    plain = tmp_path / "plain.db"
    _run(plain, "--engine", engine)
    assert read_learning_curve(plain).empty
    cols = ["seed", "phase", "episode", "return", "foods"]
    assert read_episode_metrics(db)[cols].equals(read_episode_metrics(plain)[cols])


def test_plug_in_agents_are_refused_in_one_line(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.delenv("NUTRIBENCH_DB", raising=False)
    agents = tmp_path / "agents"
    shutil.copytree(REPO / "regimes" / "agents", agents)
    shutil.copy(REPO / "examples" / "agents" / "recurrent_ppo.toml", agents)
    monkeypatch.setenv("NUTRIBENCH_AGENTS", str(agents))
    db = tmp_path / "r.db"
    args = ["run", "--regimes", "run0", "--algos", "mc,recurrent_ppo", "--seeds", "0", "--episodes", "1"]
    res = CliRunner().invoke(app, [*args, "--db", str(db), "--eval-every", "1"])
    assert res.exit_code == 2 and "--eval-every: recurrent_ppo" in res.output, res.output
    assert len(res.output.strip().splitlines()) == 1 and not db.exists()


def test_the_migration_upgrades_a_0005_database(tmp_path: Path) -> None:
    db = tmp_path / "old.db"
    engine = make_engine(database_url(db), writer=True)
    with engine.begin() as conn:
        upgrade_connection(conn, "0005")
        conn.execute(text("INSERT INTO regimes VALUES (1, 'run0', 1, 'aa', '{}', NULL, '2026-01-01')"))
        conn.execute(text("INSERT INTO agent_configs VALUES (1, 'ppo', 'ppo', 1, 'bb', '{}', NULL, '2026-01-01')"))
        conn.execute(
            text(
                "INSERT INTO jobs (id, regime_id, agent_config_id, seed, episodes, eval_episodes, status, attempt, "
                "failures, episodes_done, created_at, fake, engine) "
                "VALUES (1, 1, 1, 0, 2, 0, 'done', 1, 0, 2, '2026-01-01', 0, 'sb3')"
            )
        )
        conn.execute(text('INSERT INTO diagnostics (job_id, "update", timestep) VALUES (1, 0, 100)'))
    engine.dispose()
    assert "validation_episodes" not in {r[0] for r in sql(db, "SELECT name FROM sqlite_master")}
    res = CliRunner().invoke(app, ["run", "--upgrade-only", "--db", str(db)])
    assert res.exit_code == 0 and "upgraded from 0005" in res.output, res.output
    assert sql(db, "SELECT version_num FROM nutribench_alembic_version") == [("0007",)]
    assert sql(db, "SELECT count(*) FROM jobs") == sql(db, "SELECT count(*) FROM diagnostics") == [(1,)]
    con = sqlite3.connect(db)
    con.execute(
        'INSERT INTO validation_episodes (job_id, train_day, episode, "return", foods, final_distance, '
        "overshoot_ratio, final_C, final_F, final_P, never, planner) VALUES (1, 2, 0, -1.0, 3, 0.5, 0.1, 1, 1, 1, -2, 2)"
    )
    con.commit()
    con.close()
    rows = sql(db, 'SELECT regime, algo, seed, engine, train_day, episode, "return", gap_closed FROM learning_curve')
    assert rows == [("run0", "ppo", 0, "sb3", 2, 0, -1.0, 0.25)]
    assert tuple(c[1] for c in sql(db, "PRAGMA table_info(learning_curve)")) == LEARNING_CURVE_COLUMNS
