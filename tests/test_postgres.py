"""PostgreSQL as a first-class results database, against a real throwaway server
(tests/pg.py): the alembic chain, the views and the pandas one-liner, claims by two drivers
at once, a killed driver's jobs taken over, an upgrade from the first revision, and readers
during a run. The jobs are the synthetic ones (``NUTRIBENCH_JOB=fake``)."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from datetime import timedelta
from pathlib import Path

import pandas as pd
import pytest
from sqlalchemy import create_engine, inspect, text
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.scheduler.status import status_table
from nutribench.store import StoreError, head_revision, open_store, read_episode_metrics
from nutribench.store.models import EPISODE_METRICS_COLUMNS, STALE_AFTER_S, VIEWS
from tests.conftest import wait_for
from tests.test_store import make_0001

REPO = Path(__file__).resolve().parents[1]
NUTRIBENCH = str(Path(sys.executable).parent / "nutribench")

# a throwaway server for the session, drivers in subprocesses (one killed): minutes in all
pytestmark = [pytest.mark.slow, pytest.mark.serial]
runner = CliRunner()


def sql(url: str, query: str, **params) -> list[tuple]:
    engine = create_engine(url)
    try:
        with engine.begin() as conn:
            result = conn.execute(text(query), params)
            return [tuple(r) for r in result] if result.returns_rows else []
    finally:
        engine.dispose()


# The views leave a dry run's (fake) jobs out; their rows are read from the tables, joined to
# names as the episode_metrics view joins them.
EPISODE_ROWS = (
    'SELECT r."name" AS regime, r."version" AS regime_version, a."name" AS algo, '
    'a."version" AS algo_version, j."seed" AS seed, j."episodes" AS budget, e.* FROM episodes e '
    'JOIN jobs j ON j."id" = e."job_id" JOIN regimes r ON r."id" = j."regime_id" '
    'JOIN agent_configs a ON a."id" = j."agent_config_id"'
)


def episode_rows(db: str | Path) -> pd.DataFrame:
    """Every stored episode with its job's names (dry-run jobs kept), in a stable order."""
    engine = create_engine(db if isinstance(db, str) else f"sqlite:///{db}")
    try:
        df = pd.read_sql(text(EPISODE_ROWS), engine)
    finally:
        engine.dispose()
    return df.sort_values(["job_id", "phase", "episode"]).reset_index(drop=True)


def _env(tmp_path: Path, **extra: str) -> dict[str, str]:
    env = dict(os.environ, NUTRIBENCH_JOB="fake", **extra)
    env.pop("NUTRIBENCH_AGENTS", None)
    env.pop("NUTRIBENCH_REGIMES", None)
    return env


def _run_cmd(url: str, *args: str) -> list[str]:
    return [NUTRIBENCH, "run", "--db", url, "--regimes", "run0,run1", "--algos", "mc,ppo,sac", *args]


def test_a_grid_status_report_and_pandas_on_postgres(pg_url: str, tmp_path: Path) -> None:
    """The first contact that failed (MC's max_grad_norm = inf was stored as JSON Infinity)."""
    env = _env(tmp_path)
    done = subprocess.run(
        _run_cmd(pg_url, "--seeds", "0,1", "--episodes", "5", "--eval-episodes", "2"),
        env=env,
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    assert "12 jobs: 12 done" in done.stderr
    assert sql(pg_url, "SELECT body->>'max_grad_norm' FROM agent_configs WHERE name = 'mc'") == [("inf",)]
    engine = create_engine(pg_url)
    with engine.connect() as conn:
        assert set(inspect(conn).get_view_names()) >= set(VIEWS)
    df = pd.read_sql("SELECT * FROM episode_metrics", engine)  # the README's one-liner, unchanged
    engine.dispose()
    assert tuple(df.columns) == EPISODE_METRICS_COLUMNS
    assert len(df) == 0  # a dry run's jobs are marked fake: the view leaves them out
    assert sql(pg_url, "SELECT count(*), sum(CASE WHEN fake THEN 1 ELSE 0 END) FROM jobs") == [(12, 12)]
    assert len(read_episode_metrics(pg_url)) == len(df)
    assert len(episode_rows(pg_url)) == 12 * (5 + 2)  # every row stored
    report = status_table(pg_url)
    assert (report.totals["done"], report.totals["jobs"]) == (12, 12)
    again = subprocess.run(
        _run_cmd(pg_url, "--seeds", "0,1", "--episodes", "5", "--eval-episodes", "2"),
        env=env,
        capture_output=True,
        text=True,
        cwd=tmp_path,
        timeout=120,
    )
    assert again.returncode == 0 and "12 already done" in again.stderr, again.stderr
    res = runner.invoke(app, ["report", "--db", pg_url, "--table", "results", "--out", str(tmp_path / "rep")])
    assert res.exit_code == 2 and "holds no finished episodes" in res.output, res.output  # draws no dry-run row
    assert not (tmp_path / "rep" / "table_results.md").exists()
    # the same rows as a real run's results: the view (its filter on PostgreSQL) and the report show them
    sql(pg_url, "UPDATE jobs SET fake = false")
    engine = create_engine(pg_url)
    df = pd.read_sql("SELECT * FROM episode_metrics", engine)
    engine.dispose()
    assert tuple(df.columns) == EPISODE_METRICS_COLUMNS and len(df) == 12 * (5 + 2)
    assert len(read_episode_metrics(pg_url)) == len(df)
    res = runner.invoke(app, ["report", "--db", pg_url, "--table", "results", "--out", str(tmp_path / "rep")])
    assert res.exit_code == 0, res.output
    assert (tmp_path / "rep" / "table_results.md").is_file()


def test_two_drivers_at_once_never_run_a_job_twice_on_postgres(pg_url: str, tmp_path: Path) -> None:
    log = tmp_path / "log"
    log.mkdir()
    env = _env(tmp_path, NUTRIBENCH_FAKE_SECONDS="0.01", NUTRIBENCH_FAKE_LOG=str(log))
    cmd = _run_cmd(pg_url, "--seeds", "0,1,2", "--episodes", "20", "--eval-episodes", "1", "--workers", "2")
    procs = [
        subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        for _ in range(2)
    ]
    outs = [p.communicate(timeout=120)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    executions = sorted(f.name.split("-")[0] for f in log.iterdir())
    assert len(executions) == 18 and len(set(executions)) == 18  # every job exactly once
    done = [int(re.search(r"18 jobs: (\d+) done", out).group(1)) for out in outs]
    assert sum(done) == 18  # the two drivers shared the grid
    assert sql(pg_url, "SELECT count(*), sum(CASE WHEN status = 'done' THEN 1 ELSE 0 END) FROM jobs") == [(18, 18)]
    assert sql(pg_url, "SELECT count(*) FROM episodes") == [(18 * 21,)]
    assert sql(
        pg_url,
        "SELECT count(*) FROM (SELECT job_id, phase, episode FROM episodes GROUP BY 1, 2, 3 HAVING count(*) > 1) d",
    ) == [(0,)]


def test_a_killed_driver_s_jobs_are_taken_over_on_postgres(pg_url: str, tmp_path: Path) -> None:
    """kill -9 of a driver and its workers (a host that died): its jobs stay `running` with a
    heartbeat that stops; a second driver waits until it is stale by the database's clock,
    then runs them. Heartbeats are moved back to STALE_AFTER_S - 4 s to keep the test short."""
    log = tmp_path / "log"
    log.mkdir()
    env = _env(tmp_path, NUTRIBENCH_FAKE_SECONDS="0.05", NUTRIBENCH_FAKE_LOG=str(log))
    cmd = _run_cmd(pg_url, "--seeds", "0", "--episodes", "200", "--eval-episodes", "1", "--workers", "2")
    victim = subprocess.Popen(
        cmd, env=env, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True
    )
    try:
        wait_for(
            lambda: (
                bool(sql(pg_url, "SELECT 1 FROM information_schema.tables WHERE table_name = 'jobs'"))
                and sql(pg_url, "SELECT count(*) FROM jobs WHERE status = 'running' AND episodes_done > 0") == [(2,)]
            ),
            timeout=120,  # a precondition (workers started, torch imported): as test_scheduler's Ctrl-C test
        )
    finally:
        os.killpg(victim.pid, signal.SIGKILL)
        victim.wait(timeout=30)
    assert sql(pg_url, "SELECT count(*) FROM jobs WHERE status = 'running'") == [(2,)]
    assert sql(pg_url, "SELECT count(*) FROM episodes") == [(0,)]  # rows only for finished jobs
    sql(
        pg_url,
        "UPDATE jobs SET heartbeat_at = timezone('UTC', now()) - make_interval(secs => :s) WHERE status = 'running'",
        s=STALE_AFTER_S - 4,
    )
    report = status_table(pg_url)
    assert (report.totals["running"], report.totals["orphaned"]) == (2, 0)  # not stale yet
    ((beat,),) = sql(pg_url, "SELECT max(heartbeat_at) FROM jobs WHERE status = 'running'")
    rescue = subprocess.run(
        cmd, env=dict(env, NUTRIBENCH_FAKE_SECONDS="0.001"), cwd=tmp_path, capture_output=True, text=True, timeout=180
    )
    assert rescue.returncode == 0, rescue.stderr
    assert "6 jobs: 6 done" in rescue.stderr
    ((taken_over,),) = sql(pg_url, "SELECT min(started_at) FROM jobs WHERE attempt = 2")
    assert taken_over > beat + timedelta(seconds=STALE_AFTER_S)  # it waited for the heartbeat to go stale
    assert sql(pg_url, "SELECT count(*), sum(CASE WHEN status = 'done' THEN 1 ELSE 0 END), max(attempt) FROM jobs") == [
        (6, 6, 2)
    ]
    assert sql(pg_url, "SELECT count(*) FROM episodes") == [(6 * 201,)]
    executions = [f.name.split("-")[0] for f in log.iterdir()]
    assert len(executions) == 8  # 2 killed half-way + 6 in the rescuing driver


def test_upgrade_from_the_first_revision_on_postgres(pg_url: str) -> None:
    make_0001(pg_url)
    with pytest.raises(
        StoreError, match=r"revision 0001, this nutribench needs 0007: run `nutribench run --upgrade-only"
    ):
        open_store(pg_url)
    res = runner.invoke(app, ["run", "--upgrade-only", "--db", pg_url])
    assert res.exit_code == 0 and "upgraded from 0001" in " ".join(res.output.split()), res.output
    store = open_store(pg_url)
    assert store.revision == head_revision()
    store.dispose()
    df = read_episode_metrics(pg_url)
    assert list(df["episode"]) == [0, 1] and set(df["algo"]) == {"ppo"}


def test_status_and_report_read_while_a_run_writes_on_postgres(pg_url: str, tmp_path: Path) -> None:
    env = _env(tmp_path, NUTRIBENCH_FAKE_SECONDS="0.01")
    cmd = _run_cmd(pg_url, "--seeds", "0,1", "--episodes", "100", "--eval-episodes", "1", "--workers", "2")
    proc = subprocess.Popen(cmd, env=env, cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    seen_partial = False
    try:
        wait_for(
            lambda: bool(sql(pg_url, "SELECT 1 FROM information_schema.tables WHERE table_name = 'jobs'")), timeout=60
        )
        while proc.poll() is None:
            report = status_table(pg_url)
            per_job = sql(pg_url, "SELECT job_id, count(*) FROM episodes GROUP BY job_id")
            assert all(n == 101 for _, n in per_job), per_job  # a job's rows appear all at once
            assert len(read_episode_metrics(pg_url)) == 0  # the dry run's rows: never in the view
            seen_partial |= 0 < report.totals["done"] < 12
            time.sleep(0.2)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, out
    assert seen_partial
    assert status_table(pg_url).totals["done"] == 12
    assert sql(pg_url, "SELECT count(*) FROM episodes") == [(12 * 101,)]


def test_db_copy_moves_a_sqlite_database_into_postgres(
    pg_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """README "Running on several machines": an existing SQLite database's results moved
    into PostgreSQL, then the grid goes on there."""
    from nutribench.scheduler.driver import GridSettings, run_grid
    from nutribench.scheduler.synthetic import synthetic_job

    monkeypatch.chdir(tmp_path)
    db = tmp_path / "lab.db"
    assert (
        run_grid(GridSettings(db, ["run0", "run3"], ["mc", "ppo"], [0], 6, 2, job_fn=synthetic_job, display=False)).done
        == 4
    )
    res = runner.invoke(app, ["db", "copy", str(db), pg_url])
    assert res.exit_code == 0, res.output
    assert "episodes: 32 rows" in res.output and "4 jobs" in res.output
    before, after = episode_rows(db), episode_rows(pg_url)
    assert len(before) == 32
    pd.testing.assert_frame_equal(before, after, check_dtype=False)
    assert sql(pg_url, "SELECT count(*), sum(CASE WHEN fake THEN 1 ELSE 0 END) FROM jobs") == [
        (4, 4)
    ]  # still a dry run's
    assert len(read_episode_metrics(db)) == len(read_episode_metrics(pg_url)) == 0
    assert sql(pg_url, "SELECT body->>'max_grad_norm' FROM agent_configs WHERE name = 'mc'") == [("inf",)]
    again = runner.invoke(app, ["db", "copy", str(db), pg_url])  # never on top of results
    assert again.exit_code == 2 and "already holds rows" in again.output and "4 jobs" in again.output
    more = run_grid(
        GridSettings(pg_url, ["run0", "run3"], ["mc", "ppo"], [0, 1], 6, 2, job_fn=synthetic_job, display=False)
    )
    assert (more.done, more.skipped) == (4, 4)  # new job ids follow the copied ones
    assert sql(pg_url, "SELECT count(*), count(DISTINCT id) FROM jobs") == [(8, 8)]


def test_two_hosts_simulated_one_dask_cluster_two_drivers_one_database(
    pg_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A two-host lab on one machine: a dask cluster of separate worker processes, and two
    drivers started at once from two working folders on one PostgreSQL database, sharing a
    models folder. Every job runs exactly once."""
    import distributed

    log = tmp_path / "log"
    log.mkdir()
    monkeypatch.setenv("NUTRIBENCH_FAKE_LOG", str(log))  # the workers inherit it
    monkeypatch.setenv("NUTRIBENCH_FAKE_SECONDS", "0.005")
    hosts = [tmp_path / "host-a", tmp_path / "host-b"]
    for h in hosts:
        h.mkdir()
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        address = cluster.scheduler_address.replace("tcp://", "dask://")
        cmd = _run_cmd(
            pg_url,
            "--seeds",
            "0,1,2",
            "--episodes",
            "20",
            "--eval-episodes",
            "1",
            "--executor",
            address,
            "--models-dir",
            str(tmp_path / "shared-models"),
        )
        procs = [
            subprocess.Popen(
                cmd, env=_env(tmp_path), cwd=h, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
            )
            for h in hosts
        ]
        outs = [p.communicate(timeout=180)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    executions = sorted(f.name.split("-")[0] for f in log.iterdir())
    assert len(executions) == 18 and len(set(executions)) == 18
    assert sql(pg_url, "SELECT count(*), sum(CASE WHEN status = 'done' THEN 1 ELSE 0 END) FROM jobs") == [(18, 18)]
    assert sql(pg_url, "SELECT count(*) FROM episodes") == [(18 * 21,)]
    assert sql(pg_url, "SELECT count(DISTINCT host) FROM jobs") == [(1,)]  # one machine, honestly


def test_a_driver_registering_a_grid_waits_for_another_registering_it(pg_url: str) -> None:
    """Two drivers started at the same moment on a new grid: on PostgreSQL both inserted the
    same config row and one died on the unique key (7 of 30 driver starts, in 15 scripted pairs
    on new databases). Registration now holds an advisory lock, as SQLite's BEGIN IMMEDIATE does.
    Here driver A has inserted the configs and not yet committed; driver B registers the same
    grid meanwhile, and must end with the same rows, not an IntegrityError."""
    import threading

    from nutribench.scheduler.grid import resolve_grid
    from nutribench.scheduler.registration import _register, load_grid_configs, register_grid
    from nutribench.store import RegimeConfig, session_scope
    from nutribench.store.engine import REGISTRATION_LOCK, hold_write_lock

    grid = resolve_grid(preset=None, regimes=["run0"], algos=["ppo"], seeds="0,1", episodes=2, eval_episodes=1)
    regimes, agents = load_grid_configs(grid)
    store_a, store_b = open_store(pg_url, writer=True), open_store(pg_url, writer=True)
    outcome: list = []

    def driver_b() -> None:
        try:
            outcome.append(register_grid(store_b, grid, regimes, agents))
        except Exception as e:  # noqa: BLE001 - the assertion shows it
            outcome.append(e)

    with session_scope(store_a.engine) as s:  # driver A, mid-registration
        hold_write_lock(s, REGISTRATION_LOCK)
        _register(s, RegimeConfig, regimes)
        b = threading.Thread(target=driver_b)
        b.start()
        time.sleep(0.5)  # B reaches the point where it waits for A
    b.join(timeout=60)
    store_a.dispose()
    store_b.dispose()
    assert len(outcome) == 1 and isinstance(outcome[0], list) and len(outcome[0]) == 2, outcome
    assert sql(pg_url, "SELECT count(*) FROM regimes") == [(1,)]
