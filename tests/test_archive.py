"""``nutribench db export`` / ``db import``: a grid run in parts on disks that are not shared
(another machine, a later working session) carried into one database, exactly."""

from __future__ import annotations

import json
import sqlite3
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.config.loading import content_sha256
from nutribench.scheduler.driver import GridSettings, run_grid
from nutribench.scheduler.synthetic import synthetic_job
from nutribench.store import read_jobs

runner = CliRunner()
SORT = ["regime", "algo", "seed", "phase", "episode"]


def _grid(db: Path, algos: list[str], seeds: list[int]):
    return run_grid(GridSettings(db, ["run0", "run3"], algos, seeds, 6, 2, job_fn=synthetic_job, display=False))


def _out(res) -> str:
    return " ".join(res.output.split())  # the console wraps long lines


# The grids here are dry runs (fake jobs), which the views leave out (revision 0004): the
# rows are read from the tables, names joined in as the views do.
_JOINED = (
    "SELECT r.name AS regime, r.version AS regime_version, a.name AS algo, a.version AS algo_version, "
    "j.seed AS seed, j.episodes AS budget, t.* FROM {table} t JOIN jobs j ON j.id = t.job_id "
    "JOIN regimes r ON r.id = j.regime_id JOIN agent_configs a ON a.id = j.agent_config_id"
)


def _table(db: Path, table: str) -> pd.DataFrame:
    with sqlite3.connect(db) as c:
        return pd.read_sql_query(_JOINED.format(table=table), c)


def _metrics(db: Path) -> pd.DataFrame:
    return _table(db, "episodes").drop(columns="job_id").sort_values(SORT).reset_index(drop=True)


def _trajectories(db: Path) -> pd.DataFrame:
    return _table(db, "eval_steps").drop(columns="job_id")


@pytest.mark.slow
def test_a_grid_run_in_two_parts_merges_into_one_database(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    part1, part2, merged = (tmp_path / f"{n}.db" for n in ("part1", "part2", "merged"))
    assert _grid(part1, ["mc"], [0, 1]).done == 4
    assert _grid(part2, ["mc", "ppo"], [0, 1]).done == 8
    with sqlite3.connect(part1) as c:  # part 1 was stopped before its seed-1 jobs finished
        c.execute("UPDATE jobs SET status = 'pending' WHERE seed = 1")
    res = runner.invoke(app, ["db", "export", str(tmp_path / "p1.npz"), "--db", str(part1)])
    assert res.exit_code == 0, res.output
    assert "2 jobs, 16 episodes, 200 evaluation steps" in _out(res)  # only done jobs travel
    res = runner.invoke(app, ["db", "export", str(tmp_path / "p2.npz"), "--db", str(part2), "--algos", "ppo"])
    assert res.exit_code == 0 and "4 jobs" in _out(res), res.output
    # a part can also be cut by regime: ppo on run3 only (2 seeds)
    res = runner.invoke(
        app, ["db", "export", str(tmp_path / "p3.npz"), "--db", str(part2), "--algos", "ppo", "--regimes", "run3"]
    )
    assert res.exit_code == 0 and "2 jobs" in _out(res), res.output
    res = runner.invoke(app, ["db", "import", str(tmp_path / "p3.npz"), "--db", str(tmp_path / "p3.db")])
    assert res.exit_code == 0, res.output
    assert set(map(tuple, read_jobs(tmp_path / "p3.db")[["regime", "algo"]].values)) == {("run3", "ppo")}

    for archive in ("p1.npz", "p2.npz"):
        res = runner.invoke(app, ["db", "import", str(tmp_path / archive), "--db", str(merged)])
        assert res.exit_code == 0, res.output
    done1 = _metrics(part1).merge(read_jobs(part1).query("status == 'done'")[["regime", "algo", "seed"]])
    expected = pd.concat([done1, _metrics(part2).query("algo == 'ppo'")]).sort_values(SORT).reset_index(drop=True)
    assert len(expected) == 6 * 8  # 2 done mc jobs of part 1, 4 ppo jobs of part 2
    pd.testing.assert_frame_equal(_metrics(merged), expected, check_dtype=False)
    traj = [
        _trajectories(db)
        .query("algo == 'ppo'")
        .sort_values(["regime", "seed", "episode", "step"])
        .reset_index(drop=True)
        for db in (merged, part2)
    ]
    assert len(traj[0]) == 4 * 2 * 50
    pd.testing.assert_frame_equal(*traj, check_dtype=False)
    # the grid goes on in the merged database: only the missing MC seed-1 jobs run
    more = _grid(merged, ["mc", "ppo"], [0, 1])
    assert (more.done, more.skipped) == (2, 6)

    # importing again keeps what is there
    again = runner.invoke(app, ["db", "import", str(tmp_path / "p1.npz"), "--db", str(merged)])
    assert again.exit_code == 0 and "0 jobs imported" in _out(again) and "2 already done there and kept" in _out(again)
    assert len(read_jobs(merged)) == 8 and set(read_jobs(merged)["status"]) == {"done"}
    # an archived result fills a job the database holds pending (a registered, unrun grid)
    with sqlite3.connect(part2) as c:
        c.execute(
            "UPDATE jobs SET status = 'pending' WHERE id IN (SELECT j.id FROM jobs j JOIN agent_configs a "
            "ON a.id = j.agent_config_id WHERE a.name = 'ppo')"
        )
        c.execute("DELETE FROM episodes WHERE job_id IN (SELECT id FROM jobs WHERE status = 'pending')")
        c.execute("DELETE FROM eval_steps WHERE job_id IN (SELECT id FROM jobs WHERE status = 'pending')")
    before = _metrics(merged).query("algo == 'ppo'").reset_index(drop=True)
    res = runner.invoke(app, ["db", "import", str(tmp_path / "p2.npz"), "--db", str(part2)])
    assert res.exit_code == 0 and "4 jobs imported" in _out(res), res.output
    assert len(read_jobs(part2)) == 8 and set(read_jobs(part2)["status"]) == {"done"}
    pd.testing.assert_frame_equal(
        _metrics(part2).query("algo == 'ppo'").reset_index(drop=True), before, check_dtype=False
    )


def test_provenance_and_exact_values_survive_the_trip(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    src, dst = tmp_path / "src.db", tmp_path / "dst.db"
    _grid(src, ["mc"], [0])
    with sqlite3.connect(src) as c:  # values no float32 or decimal rounding would keep
        c.execute(
            "UPDATE episodes SET \"return\" = -7.123456789012345 + episode * 1e-13, entropy = NULL WHERE phase = 'eval'"
        )
        c.execute(
            "UPDATE jobs SET git_commit = 'abc123', git_dirty = 0, batch_id = 'b7', batch_size = 2, device = 'cuda:0', "
            "source = 'train_mine.py', source_sha256 = '" + "ab" * 32 + "'"
        )
    runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(src)])
    assert runner.invoke(app, ["db", "import", str(tmp_path / "a.npz"), "--db", str(dst)]).exit_code == 0
    assert len(_metrics(src)) == 2 * 8
    pd.testing.assert_frame_equal(_metrics(dst), _metrics(src), check_exact=True, check_dtype=False)
    assert _metrics(dst).query("phase == 'eval'")["entropy"].isna().all()
    a, b = (read_jobs(db).drop(columns=["job_id"], errors="ignore") for db in (src, dst))
    for col in (
        "seed",
        "episodes",
        "eval_episodes",
        "git_commit",
        "git_dirty",
        "wall_seconds",
        "engine",
        "started_at",
        "finished_at",
        "host",
        "fake",
        "batch_id",
        "batch_size",
        "device",
        "source",
        "source_sha256",
    ):
        assert list(a[col]) == list(b[col]), col
    assert set(b["git_commit"]) == {"abc123"}
    assert b["model_path"].isna().all()  # a stored path is not carried into another database


def test_bad_archives_and_conflicts_are_one_line_errors(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    src, dst = tmp_path / "src.db", tmp_path / "dst.db"
    _grid(src, ["mc"], [0])
    res = runner.invoke(app, ["db", "import", str(tmp_path / "missing.npz"), "--db", str(dst)])
    assert res.exit_code == 2 and "no such file" in _out(res)
    (tmp_path / "junk.npz").write_bytes(b"not a zip")
    res = runner.invoke(app, ["db", "import", str(tmp_path / "junk.npz"), "--db", str(dst)])
    assert res.exit_code == 2 and "not a results archive" in _out(res)
    np.savez(tmp_path / "other.npz", x=np.zeros(3))
    res = runner.invoke(app, ["db", "import", str(tmp_path / "other.npz"), "--db", str(dst)])
    assert res.exit_code == 2 and "not a results archive" in _out(res)
    res = runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(src), "--algos", "sac"])
    assert res.exit_code == 2 and "no done jobs of sac" in _out(res) and not (tmp_path / "a.npz").exists()
    res = runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(src), "--regimes", "run5"])
    assert res.exit_code == 2 and "no done jobs of run5" in _out(res) and not (tmp_path / "a.npz").exists()
    # the same config version with other content (a file changed without a version bump, its
    # hash honestly recomputed): the databases disagree, nothing is written
    assert runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(src)]).exit_code == 0
    _grid(dst, ["ppo"], [0])
    with sqlite3.connect(src) as c:
        body = json.loads(c.execute("SELECT body FROM agent_configs WHERE name = 'mc'").fetchone()[0])
        body["description"] += " (edited)"
        c.execute(
            "UPDATE agent_configs SET body = ?, sha256 = ? WHERE name = 'mc'", (json.dumps(body), content_sha256(body))
        )
    assert runner.invoke(app, ["db", "export", str(tmp_path / "b.npz"), "--db", str(src)]).exit_code == 0
    assert runner.invoke(app, ["db", "import", str(tmp_path / "a.npz"), "--db", str(dst)]).exit_code == 0
    before = len(_metrics(dst))
    assert before == 4 * 8
    res = runner.invoke(app, ["db", "import", str(tmp_path / "b.npz"), "--db", str(dst)])
    assert res.exit_code == 2 and "mc v" in _out(res) and "other content" in _out(res)
    assert len(_metrics(dst)) == before


def test_a_job_another_driver_runs_is_not_overwritten(tmp_path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    src, dst = tmp_path / "src.db", tmp_path / "dst.db"
    _grid(src, ["mc"], [0])
    _grid(dst, ["mc"], [0])
    runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(src)])
    with sqlite3.connect(dst) as c:
        c.execute(
            "UPDATE jobs SET status = 'running', owner = 'elsewhere:1:x', heartbeat_at = datetime('now') WHERE id = 1"
        )
        c.execute("DELETE FROM episodes WHERE job_id = 1")
    res = runner.invoke(app, ["db", "import", str(tmp_path / "a.npz"), "--db", str(dst)])
    assert res.exit_code == 2 and "is running" in _out(res) and "elsewhere" in _out(res)
    with sqlite3.connect(dst) as c:
        assert c.execute("SELECT count(*) FROM episodes WHERE job_id = 1").fetchone() == (0,)


def test_an_import_writes_each_jobs_rows_in_one_statement_whatever_is_null(tmp_path, monkeypatch) -> None:
    """Rows that differ in which values are NULL share one executemany (the ORM's bulk insert left a
    None out of its row's INSERT and so split them, a statement every few rows on a real archive)."""
    from sqlalchemy import event
    from sqlalchemy.engine import Engine

    monkeypatch.chdir(tmp_path)
    src, dst = tmp_path / "src.db", tmp_path / "dst.db"
    _grid(src, ["mc"], [0])
    with sqlite3.connect(src) as c:  # every other episode with no entropy and no overshoot step
        c.execute("UPDATE episodes SET entropy = NULL, first_overshoot_step = NULL WHERE episode % 2 = 0")
        c.execute("UPDATE episodes SET first_overshoot_step = 3 WHERE episode % 2 = 1")
    runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(src)])
    rows_per_statement: list[int] = []

    def seen(conn, cursor, statement, parameters, context, executemany):
        if statement.startswith("INSERT INTO episodes"):
            rows_per_statement.append(len(parameters) if executemany else 1)

    event.listen(Engine, "before_cursor_execute", seen)
    try:
        assert runner.invoke(app, ["db", "import", str(tmp_path / "a.npz"), "--db", str(dst)]).exit_code == 0
    finally:
        event.remove(Engine, "before_cursor_execute", seen)
    assert len(_metrics(src)) == 2 * 8
    assert rows_per_statement == [8, 8]  # two jobs (run0, run3), their 8 episodes each at once
    pd.testing.assert_frame_equal(_metrics(dst), _metrics(src), check_exact=True, check_dtype=False)
    assert _metrics(dst)["entropy"].isna().sum() == 8
