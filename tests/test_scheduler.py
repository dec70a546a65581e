"""The driver of ``nutribench run`` with the synthetic job (no training): grid expansion,
end-to-end storage, resume, config versioning, dying and failing workers, Ctrl-C,
concurrent drivers, status, and a dask cluster."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
from datetime import datetime
from pathlib import Path

import pandas as pd
import pytest
from sqlalchemy import create_engine, text
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.cli.run import STOP_SIGNALS
from nutribench.config import list_regimes
from nutribench.scheduler.driver import GridSettings, RunError, run_grid
from nutribench.scheduler.grid import PRESETS, GridError, parse_seeds, resolve_grid
from nutribench.scheduler.lifecycle import MAX_FAILURES
from nutribench.scheduler.status import status_table
from nutribench.scheduler.synthetic import synthetic_job
from nutribench.store.models import STALE_AFTER_S
from tests.conftest import run_cli_args, wait_for
from tests.fake_jobs import EnvBatch, EnvJob, HalfBatch

REPO = Path(__file__).resolve().parents[1]
NUTRIBENCH = str(Path(sys.executable).parent / "nutribench")
H = 50  # steps per fake evaluation episode


@pytest.fixture
def regimes(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A private copy of regimes/ (regime and agent config files) the test may edit."""
    folder = tmp_path / "regimes"
    shutil.copytree(REPO / "regimes", folder)
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(folder))
    monkeypatch.delenv("NUTRIBENCH_AGENTS", raising=False)
    return folder


def sql(db: Path, query: str) -> list[tuple]:
    engine = create_engine(f"sqlite:///{db}")
    try:
        with engine.connect() as conn:
            return [tuple(r) for r in conn.execute(text(query))]
    finally:
        engine.dispose()


# The views (episode_metrics, eval_trajectories) leave a dry run's jobs out; the synthetic
# jobs' rows are counted in the tables, joined to names as the views join them.
EPISODE_ROWS = (
    "SELECT r.name AS regime, r.version AS regime_version, a.name AS algo, a.version AS algo_version, "
    "j.seed AS seed, j.episodes AS budget, e.* FROM episodes e JOIN jobs j ON j.id = e.job_id "
    "JOIN regimes r ON r.id = j.regime_id JOIN agent_configs a ON a.id = j.agent_config_id"
)
TRAJECTORY_ROWS = (
    "SELECT r.name AS regime, a.name AS algo, j.seed AS seed, s.* FROM eval_steps s "
    "JOIN jobs j ON j.id = s.job_id JOIN regimes r ON r.id = j.regime_id "
    "JOIN agent_configs a ON a.id = j.agent_config_id"
)


def episode_rows(db: Path) -> pd.DataFrame:
    """Every stored episode with its job's names (the episode_metrics join, dry-run jobs kept)."""
    return pd.read_sql(EPISODE_ROWS, f"sqlite:///{db}")


def assert_views_hide_the_dry_run(db: Path) -> None:
    """A dry run's jobs are marked fake, and the views show none of their rows."""
    assert sql(db, "SELECT count(*) > 0, count(*) = sum(fake) FROM jobs") == [(1, 1)]
    assert sql(db, "SELECT count(*) FROM episode_metrics") == [(0,)]
    assert sql(db, "SELECT count(*) FROM eval_trajectories") == [(0,)]


def statuses(db: Path) -> dict[tuple[str, int], str]:
    rows = sql(db, "SELECT a.name, j.seed, j.status FROM jobs j JOIN agent_configs a ON a.id = j.agent_config_id")
    return {(a, s): st for a, s, st in rows}


# --------------------------------------------------------------------------- grid
def test_presets_and_overrides() -> None:
    assert PRESETS["smoke"].seeds == (0,) and PRESETS["smoke"].episodes == 20
    assert PRESETS["quick"].seeds == (0, 21) and PRESETS["quick"].episodes == 500
    assert PRESETS["paper"].seeds == (0, 21, 9, 2003, 1997) and PRESETS["paper"].episodes == 5000
    assert all(p.eval_episodes == 5 for p in PRESETS.values())
    g = resolve_grid(preset="quick", regimes=["run0", "run3"], algos=["ppo"], episodes=7)
    assert (g.seeds, g.episodes, g.eval_episodes) == ((0, 21), 7, 5)
    assert g.cells() == [("run0", "ppo", 0), ("run0", "ppo", 21), ("run3", "ppo", 0), ("run3", "ppo", 21)]
    g = resolve_grid(preset="smoke", regimes=["run0"], algos=["sac"], seeds="9,2003", eval_episodes=2)
    assert (g.seeds, g.episodes, g.eval_episodes) == ((9, 2003), 20, 2)


@pytest.mark.parametrize("bad", ["", "0,,1", "a", "1.5", "-1", "0,0", "0x1", "0;1"])
def test_malformed_seeds_are_one_line_errors(bad: str) -> None:
    with pytest.raises(GridError) as e:
        parse_seeds(bad)
    assert "\n" not in str(e.value) and "--seeds" in str(e.value)


def test_parse_seeds() -> None:
    assert parse_seeds("0, 21,9") == (0, 21, 9)


# --------------------------------------------------------------------------- end to end
@pytest.mark.slow
def test_smoke_grid_stores_every_row_and_rerun_does_nothing(regimes: Path, tmp_path: Path) -> None:
    db, log = tmp_path / "r.db", tmp_path / "log"
    log.mkdir()
    algos = ["mc", "ddqn", "ppo", "sac", "gru_ppo"]
    g = resolve_grid(preset="smoke", regimes=list_regimes(), algos=algos)
    settings = GridSettings(
        db,
        g.regimes,
        g.algos,
        g.seeds,
        g.episodes,
        g.eval_episodes,
        workers=2,
        job_fn=EnvJob(NUTRIBENCH_FAKE_LOG=str(log)),
        display=False,
    )
    s = run_grid(settings)
    n = 7 * 5
    assert (s.done, s.failed, s.skipped, s.exit_code) == (n, 0, 0, 0)
    df = episode_rows(db)
    assert len(df) == n * (20 + 5)
    assert df.groupby("phase").size().to_dict() == {"eval": n * 5, "train": n * 20}
    assert set(df["regime"]) == set(list_regimes()) and set(df["algo"]) == set(algos)
    traj = pd.read_sql(TRAJECTORY_ROWS, f"sqlite:///{db}")
    assert len(traj) == n * 5 * H
    assert_views_hide_the_dry_run(db)
    jobs = pd.read_sql("select * from jobs", f"sqlite:///{db}")
    assert set(jobs["status"]) == {"done"} and (jobs["episodes_done"] == 20).all()
    assert jobs["host"].notna().all() and jobs["wall_seconds"].notna().all() and jobs["owner"].isna().all()
    first = jobs.iloc[0]
    assert Path(first["model_path"]).is_file()
    assert Path(first["model_path"]).relative_to(tmp_path / "models").parts[2].startswith("seed0-ep20")
    assert len(list(log.iterdir())) == n

    again = run_grid(settings)  # the same grid again
    assert (again.done, again.skipped, again.exit_code) == (0, n, 0)
    assert len(list(log.iterdir())) == n  # nothing executed
    assert len(episode_rows(db)) == n * 25
    assert_views_hide_the_dry_run(db)


def test_changed_config_needs_a_version_bump(regimes: Path, tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    args = dict(seeds=[0], episodes=4, eval_episodes=1, workers=1, job_fn=synthetic_job, display=False)
    assert run_grid(GridSettings(db, ["run0"], ["ppo"], **args)).done == 1
    ppo = regimes / "agents" / "ppo.toml"
    v = next(int(ln.split("=")[1]) for ln in ppo.read_text().splitlines() if ln.startswith("version ="))  # as shipped
    ppo.write_text(ppo.read_text().replace("learning_rate = 1e-3", "learning_rate = 2e-3"))
    before = sql(db, "SELECT (SELECT count(*) FROM agent_configs), (SELECT count(*) FROM jobs)")
    with pytest.raises(
        RunError, match=rf"ppo\.toml: version {v} is already recorded with different content: bump the version"
    ):
        run_grid(GridSettings(db, ["run0"], ["ppo"], **args))
    assert sql(db, "SELECT (SELECT count(*) FROM agent_configs), (SELECT count(*) FROM jobs)") == before
    # the CLI says it in one line, exit 2
    res = CliRunner().invoke(
        app,
        run_cli_args(db, episodes=4),
        env={"NUTRIBENCH_JOB": "fake"},
    )
    # (after the line that says what run starts, printed before the database is opened)
    lines = [ln for ln in res.output.splitlines() if ln.strip()]
    assert res.exit_code == 2 and len(lines) == 2 and lines[0].startswith("nutribench run: 1 job"), res.output
    assert lines[1].startswith("error:") and "bump the version" in lines[1]

    ppo.write_text(ppo.read_text().replace(f"version = {v}", f"version = {v + 1}"))
    assert run_grid(GridSettings(db, ["run0"], ["ppo"], **args)).done == 1
    rows = sql(
        db, "SELECT a.version, j.status FROM jobs j JOIN agent_configs a ON a.id = j.agent_config_id ORDER BY a.version"
    )
    assert rows == [(v, "done"), (v + 1, "done")]
    df = episode_rows(db)
    assert df.groupby("algo_version").size().to_dict() == {v: 5, v + 1: 5}
    assert_views_hide_the_dry_run(db)

    run3 = regimes / "run3.toml"  # a regime file works the same way
    assert run_grid(GridSettings(db, ["run3"], ["sac"], **args)).done == 1
    run3.write_text(run3.read_text().replace('description = "', 'description = "changed: '))
    with pytest.raises(RunError, match=r"run3\.toml: version 2 is already recorded"):
        run_grid(GridSettings(db, ["run3"], ["sac"], **args))


def test_killed_worker_fails_only_its_job_and_the_next_run_completes_it(regimes: Path, tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    args = dict(seeds=[0], episodes=10, eval_episodes=2, workers=2, display=False)
    s = run_grid(GridSettings(db, ["run0"], ["mc", "ppo", "sac"], job_fn=EnvJob(kill="run0:ppo:0"), **args))
    assert (s.done, s.failed, s.exit_code) == (2, 1, 1)
    assert statuses(db) == {("mc", 0): "done", ("ppo", 0): "failed", ("sac", 0): "done"}
    ((failures, error),) = sql(db, "SELECT failures, error FROM jobs WHERE status = 'failed'")
    assert failures == 1 and "SIGKILL" in error
    df = episode_rows(db)
    assert df.groupby("algo").size().to_dict() == {"mc": 12, "sac": 12}

    s = run_grid(GridSettings(db, ["run0"], ["mc", "ppo", "sac"], job_fn=synthetic_job, **args))
    assert (s.done, s.skipped, s.exit_code) == (1, 2, 0)
    assert set(statuses(db).values()) == {"done"}
    assert len(episode_rows(db)) == 3 * 12
    assert_views_hide_the_dry_run(db)


def test_failing_job_is_retried_until_the_limit(regimes: Path, tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    failing = EnvJob(fail="run1:sac:0")
    args = dict(seeds=[0], episodes=6, eval_episodes=1, workers=1, job_fn=failing, display=False)
    for attempt in range(1, MAX_FAILURES + 1):
        s = run_grid(GridSettings(db, ["run1"], ["sac"], **args))
        assert (s.failed, s.exit_code) == (1, 1)
        assert sql(db, "SELECT failures, attempt, status FROM jobs") == [(attempt, attempt, "failed")]
    s = run_grid(GridSettings(db, ["run1"], ["sac"], **args))  # given up: not started again
    assert (s.failed, s.given_up, s.exit_code) == (0, 1, 1)
    assert sql(db, "SELECT failures, attempt FROM jobs") == [(MAX_FAILURES, MAX_FAILURES)]
    report = status_table(db)
    assert report.totals["failed"] == 1
    assert report.errors[0]["error"].startswith("RuntimeError: fake failure in run1 sac seed 0")
    assert report.errors[0]["retried"] is False


def test_retry_failed_runs_a_given_up_job_again_and_clears_its_error(regimes: Path, tmp_path: Path) -> None:
    """Once a job's cause is fixed, `run --retry-failed` tries it again;
    a job that then succeeds no longer shows its old error."""
    db = tmp_path / "r.db"
    args = dict(seeds=[0], episodes=6, eval_episodes=1, workers=1, display=False)
    for _ in range(MAX_FAILURES):
        run_grid(GridSettings(db, ["run1"], ["sac"], job_fn=EnvJob(fail="run1:sac:0"), **args))
    assert (
        run_grid(GridSettings(db, ["run1"], ["sac"], job_fn=synthetic_job, **args)).given_up == 1
    )  # the cause is fixed, still given up
    s = run_grid(GridSettings(db, ["run1"], ["sac"], job_fn=synthetic_job, retry_failed=True, **args))
    assert (s.done, s.failed, s.given_up, s.exit_code) == (1, 0, 0, 0)
    assert sql(db, "SELECT status, error FROM jobs") == [("done", None)]
    res = CliRunner().invoke(
        app,
        run_cli_args(db, "--retry-failed", regimes="run1", algos="sac", episodes=6),
        env={"NUTRIBENCH_JOB": "fake"},
    )
    assert res.exit_code == 0 and "1 already done" in res.output, res.output


def test_a_rerun_after_a_driver_crash_waits_and_takes_the_orphaned_jobs_over(regimes: Path, tmp_path: Path) -> None:
    """After a driver crash the obvious re-run does not exit 0 ("2 running in another
    driver") with work not done: it waits until their heartbeat is stale, then
    runs them; it never runs a job whose driver is alive (test_two_concurrent_runs_...)."""
    from datetime import timedelta

    from nutribench.store.engine import utcnow

    db = tmp_path / "r.db"
    args = dict(seeds=[0, 1], episodes=4, eval_episodes=1, workers=1, job_fn=synthetic_job, display=False)
    assert run_grid(GridSettings(db, ["run0"], ["ppo"], **args)).done == 2
    engine = create_engine(f"sqlite:///{db}")
    beat = utcnow() - timedelta(seconds=STALE_AFTER_S - 5)  # the crashed driver's last heartbeat
    with engine.begin() as conn:  # as a crashed driver leaves it: running, no rows written
        conn.execute(
            text("UPDATE jobs SET status='running', owner='crashed', heartbeat_at=:b, episodes_done=2 WHERE seed = 1"),
            {"b": beat},
        )
        for table in ("episodes", "eval_steps"):
            conn.execute(text(f"DELETE FROM {table} WHERE job_id IN (SELECT id FROM jobs WHERE seed = 1)"))
    report = status_table(db)  # still fresh: running
    assert (report.totals["running"], report.totals["orphaned"]) == (1, 0)
    s = run_grid(GridSettings(db, ["run0"], ["ppo"], **args))
    assert (s.done, s.busy, s.exit_code) == (1, 0, 0)
    ((started, attempt),) = sql(db, "SELECT started_at, attempt FROM jobs WHERE seed = 1")
    assert attempt == 2 and datetime.fromisoformat(started) > beat + timedelta(
        seconds=STALE_AFTER_S
    )  # taken over once stale, not before
    assert set(statuses(db).values()) == {"done"}
    with engine.begin() as conn:  # a crash long ago: status says the job is orphaned
        conn.execute(
            text("UPDATE jobs SET status='running', owner='crashed', heartbeat_at=:b WHERE seed = 1"),
            {"b": utcnow() - timedelta(seconds=STALE_AFTER_S + 5)},
        )
    report = status_table(db)
    assert (report.totals["running"], report.totals["pending"], report.totals["orphaned"]) == (0, 1, 1)
    res = CliRunner().invoke(app, ["status", "--db", str(db)])
    assert "1 of the pending jobs were running in a driver whose heartbeat stopped" in res.output.replace("\n", " ")


# --------------------------------------------------------------------------- processes
def _env(regimes: Path, **extra: str) -> dict[str, str]:
    env = dict(os.environ, NUTRIBENCH_REGIMES=str(regimes), NUTRIBENCH_JOB="fake", **extra)
    env.pop("NUTRIBENCH_AGENTS", None)
    return env


def _default_stop_signals() -> None:
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)


@pytest.mark.parametrize(
    "sig",
    [
        signal.SIGINT,
        pytest.param(signal.SIGTERM, marks=pytest.mark.slow),
        pytest.param(signal.SIGHUP, marks=pytest.mark.slow),
    ],
)  # SIGINT in the fast run
def test_ctrl_c_marks_running_jobs_interrupted_and_writes_no_rows(regimes: Path, tmp_path: Path, sig) -> None:
    """Ctrl-C, and as it a batch system's SIGTERM and a closed terminal's
    SIGHUP: the running jobs are released as interrupted at once, not left `running`."""
    db = tmp_path / "r.db"
    cmd = [
        NUTRIBENCH,
        *run_cli_args(db, "--workers", "2", algos="ppo,sac", seeds="0,21", episodes=400, eval_episodes=2),
    ]
    # The signals' default dispositions in the child, as in a terminal: a shell starts a
    # background command (`pytest ... &`) with SIGINT ignored, and the child would inherit it.
    proc = subprocess.Popen(
        cmd,
        env=_env(regimes, NUTRIBENCH_FAKE_SECONDS="0.02"),
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        preexec_fn=_default_stop_signals,
    )
    try:
        wait_for(
            lambda: (
                db.exists()
                and sql(db, "SELECT count(*) FROM sqlite_master WHERE name='jobs'")[0][0]
                and sql(db, "SELECT count(*) FROM jobs WHERE status='running' AND episodes_done > 0")[0][0] == 2
            ),
            # a precondition, not the claim: two workers start (torch imported) and store a day;
            # 30 s ran out on the 2-core machine beside two grid jobs, so room for a loaded one
            timeout=120,
        )
        report = status_table(db)  # status while the run writes
        assert (report.totals["running"], report.totals["pending"], report.totals["jobs"]) == (2, 2, 4)
        proc.send_signal(sig)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out
    assert "2 interrupted" in out
    assert sorted(statuses(db).values()) == ["interrupted", "interrupted", "pending", "pending"]
    assert sql(db, "SELECT count(*) FROM episodes")[0][0] == 0
    assert sql(db, "SELECT count(*) FROM eval_steps")[0][0] == 0
    assert sql(db, "SELECT count(*) FROM jobs WHERE owner IS NOT NULL")[0][0] == 0


@pytest.mark.slow
@pytest.mark.serial
def test_two_concurrent_runs_never_run_a_job_twice(regimes: Path, tmp_path: Path) -> None:
    db, log = tmp_path / "r.db", tmp_path / "log"
    log.mkdir()
    cmd = [NUTRIBENCH, *run_cli_args(db, "--workers", "2", regimes="run0,run1", algos="mc,ppo,sac")]
    env = _env(regimes, NUTRIBENCH_FAKE_SECONDS="0.01", NUTRIBENCH_FAKE_LOG=str(log))
    procs = [
        subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) for _ in range(2)
    ]
    # the claim is "never twice", not speed: 60 s ran out on the 2-core machine under load (two drivers and
    # two fork servers importing torch at once)
    outs = [p.communicate(timeout=180)[0] for p in procs]
    assert [p.returncode for p in procs] == [0, 0], outs
    runs = sorted(f.name.split("-")[0] for f in log.iterdir())
    assert runs == sorted(set(runs)) and len(runs) == 6  # every job exactly once
    assert sql(db, "SELECT count(*), sum(status = 'done') FROM jobs") == [(6, 6)]
    assert sql(db, "SELECT count(*) FROM episodes")[0][0] == 6 * 21


# --------------------------------------------------------------------------- CLI input
@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--algos", "ppo,bogus"], "unknown algorithm bogus: known are mc, ddqn, ppo, sac, gru_ppo"),
        (["--regimes", "run0,run9"], "unknown regime run9: known are run0"),
        (["--seeds", "0,2x"], "'2x' is not a non-negative integer"),
        (["--episodes", "0"], "at least 1 episode"),
        (["--executor", "slurm"], "unknown --executor 'slurm'"),
        (["--preset", "huge"], "unknown --preset 'huge'"),
    ],
)
def test_bad_run_options_are_one_line_and_create_nothing(regimes: Path, tmp_path: Path, args, message) -> None:
    db = tmp_path / "r.db"
    res = CliRunner().invoke(app, ["run", "--db", str(db), *args], env={"NUTRIBENCH_JOB": "fake"})
    assert res.exit_code == 2, res.output
    assert message in res.output and len(res.output.strip().splitlines()) == 1
    assert not db.exists() and not (tmp_path / "models").exists()


def test_bad_database_paths_are_one_line(regimes: Path, tmp_path: Path) -> None:
    text_file = tmp_path / "notes.txt"
    text_file.write_text("not a database\n" * 10)
    cases = [
        (text_file, "is not a SQLite database"),
        (tmp_path / "missing" / "r.db", "folder"),
        (tmp_path, "is a directory"),
    ]
    for db, message in cases:
        res = CliRunner().invoke(app, ["run", "--db", str(db), "--preset", "smoke"], env={"NUTRIBENCH_JOB": "fake"})
        assert res.exit_code == 2 and message in res.output and len(res.output.strip().splitlines()) == 1, res.output
    assert text_file.read_text().startswith("not a database")
    res = CliRunner().invoke(app, ["status", "--db", str(tmp_path / "none.db")])
    assert res.exit_code == 2 and "no results database" in res.output


@pytest.mark.slow
def test_status_json(regimes: Path, tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    run_grid(
        GridSettings(
            db, ["run2"], ["ppo", "sac"], [0, 1], 5, 1, workers=2, job_fn=EnvJob(fail="run2:sac:1"), display=False
        )
    )
    res = CliRunner().invoke(app, ["status", "--db", str(db), "--json"])
    assert res.exit_code == 0, res.output
    import json

    data = json.loads(res.output)
    assert data["totals"] == {"done": 3, "running": 0, "failed": 1, "pending": 0, "jobs": 4, "orphaned": 0}
    by_algo = {r["algo"]: r for r in data["rows"]}
    assert (by_algo["sac"]["done"], by_algo["sac"]["failed"]) == (1, 1)
    assert by_algo["sac"]["remaining_seconds"] > 0 and data["eta_seconds"] > 0  # the failed job will be retried
    assert data["errors"][0]["seed"] == 1 and "fake failure" in data["errors"][0]["error"]
    res = CliRunner().invoke(app, ["status", "--db", str(db)])
    assert res.exit_code == 0 and "fake failure" in res.output


# --------------------------------------------------------------------------- dask
@pytest.mark.slow
def test_dask_executor_runs_jobs_on_a_local_cluster(regimes: Path, tmp_path: Path) -> None:
    import distributed  # in the dev extra (and the `dask` extra)

    db = tmp_path / "r.db"
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        address = cluster.scheduler_address.replace("tcp://", "dask://")
        s = run_grid(
            GridSettings(db, ["run0"], ["ppo", "sac"], [0], 8, 2, executor=address, job_fn=synthetic_job, display=False)
        )
    assert (s.done, s.failed) == (2, 0)
    assert len(episode_rows(db)) == 2 * 10
    assert_views_hide_the_dry_run(db)


@pytest.mark.slow
def test_an_unreachable_dask_scheduler_fails_before_the_database_is_touched(regimes: Path, tmp_path: Path) -> None:
    """Nothing is written (database file, config rows, pending jobs) before the executor is reached."""
    import socket

    from nutribench.scheduler.executors import ExecutorError

    with socket.socket() as s:  # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    db = tmp_path / "r.db"
    with pytest.raises(ExecutorError, match=f"cannot reach the dask scheduler at tcp://127.0.0.1:{port}"):
        run_grid(
            GridSettings(
                db,
                ["run0"],
                ["ppo"],
                [0],
                4,
                1,
                executor=f"dask://127.0.0.1:{port}",
                job_fn=synthetic_job,
                display=False,
            )
        )
    assert not db.exists()


def test_status_prices_a_config_with_no_done_job_by_its_running_batch() -> None:
    """The batched engine: the jobs of a batch share one worker process; a config with no
    done job is priced by its running jobs' progress, not by the other algorithms' mean."""
    from datetime import timedelta

    from nutribench.scheduler.status import summarize

    now = datetime(2026, 1, 1, 12, 0, 0)
    claimed = now - timedelta(seconds=100)

    def job(algo, seed, status, wall=None, k=0, pid=None):  # the tuple status_table selects
        beat = now if status == "running" else None
        return ("run0", 1, algo, 1, seed, 100, status, beat, wall, k, 0, None, "host:1:tok", pid, claimed)

    jobs = [
        job("mc", 0, "done", wall=1.0),  # 0.01 s/day: far from SAC's cost
        job("sac", 0, "running", k=10, pid=7),  # one batch of two, 10 days each in 100 s:
        job("sac", 1, "running", k=10, pid=7),  # 5 worker-seconds per day and job
        job("sac", 2, "pending"),
    ]
    rep = summarize(jobs, now)
    assert rep.workers == 1
    sac = next(r for r in rep.rows if r.algo == "sac")
    assert sac.remaining_seconds == pytest.approx((0.9 + 0.9 + 1.0) * 100 * 5.0)
    assert rep.eta_seconds == pytest.approx(1400.0)


def test_status_prices_a_resumed_batch_by_its_own_training_time() -> None:
    """A batch resumed from a checkpoint at day 2800 of 5000, 25 minutes ago: its days before
    the resume took their own time (the worker reports each job's training seconds so far),
    so the rest is priced by those seconds, not by 2800 days in 25 minutes."""
    from datetime import timedelta

    from nutribench.scheduler.status import summarize

    now = datetime(2026, 1, 1, 12, 0, 0)
    claimed = now - timedelta(minutes=25)

    def job(seed, wall):  # the tuple status_table selects; one batch of two jobs (one worker)
        return ("run0", 1, "sac", 1, seed, 5000, "running", now, wall, 2800, 0, None, "host:1:tok", 7, claimed)

    resumed = summarize([job(0, 2800 * 3.5), job(1, 2800 * 3.5)], now)  # 3.5 worker-seconds a day and job
    assert resumed.eta_seconds == pytest.approx(2 * 2200 * 3.5)
    # a worker that reports no training seconds (an older driver's row): priced since its claim
    unreported = summarize([job(0, None), job(1, None)], now)
    assert unreported.eta_seconds == pytest.approx(2 * 2200 * 25 * 60 / (2800 * 2))


def test_status_prices_an_orphaned_batch_by_what_its_worker_last_reported() -> None:
    """A SAC batch whose driver was stopped (its heartbeat old): its jobs count as pending,
    whole, but the training seconds a day its worker last reported still price them, not the
    done jobs of a cheaper algorithm."""
    from datetime import timedelta

    from nutribench.scheduler.status import summarize

    now = datetime(2026, 1, 1, 12, 0, 0)
    stale = now - timedelta(hours=1)

    def job(algo, seed, status, wall=None, k=0, beat=None):  # the tuple status_table selects
        return ("run0", 1, algo, 1, seed, 100, status, beat, wall, k, 0, None, "host:1:tok", 7, stale)

    jobs = [
        job("mc", 0, "done", wall=1.0),  # 0.01 s/day
        job("sac", 0, "running", wall=40 * 5.0, k=40, beat=stale),  # 5 worker-seconds a day and job
        job("sac", 1, "running", wall=40 * 7.0, k=40, beat=stale),  # 7
    ]
    rep = summarize(jobs, now)
    assert rep.totals["orphaned"] == 2 and rep.totals["pending"] == 2 and rep.workers == 0
    assert rep.eta_seconds == pytest.approx(2 * 100 * 6.0)  # whole jobs, at their mean reported rate
    # a stopped job that reported no training seconds: priced as before, by the done jobs
    unreported = summarize([jobs[0], job("sac", 0, "running", k=40, beat=stale)], now)
    assert unreported.eta_seconds == pytest.approx(100 * 0.01)


def test_run_s_eta_leaves_out_the_days_a_resumed_batch_did_not_train() -> None:
    from types import SimpleNamespace

    from nutribench.scheduler.progress import eta_seconds

    run = SimpleNamespace(
        grid=SimpleNamespace(episodes=100),
        planned=2,
        attempted={1, 2},
        summary=SimpleNamespace(done=0, failed=0),
        live={1: {"k": 60}, 2: {"k": 60}},
        resumed={1: 50, 2: 50},  # both resumed at day 50: this run trained 20 days in 20 s
    )
    assert eta_seconds(run, 20.0) == pytest.approx(80.0)
    run.resumed = {}
    assert eta_seconds(run, 20.0) == pytest.approx(20.0 * 80 / 120)
    # both done now, a third job to go: their resumed days still did not cost this run anything
    run.planned, run.attempted, run.live, run.resumed = 3, {1, 2, 3}, {}, {1: 50, 2: 50}
    run.summary.done = 2
    assert eta_seconds(run, 20.0) == pytest.approx(20.0)


def test_the_driver_keeps_a_resumed_batch_s_first_day_and_training_seconds() -> None:
    from types import SimpleNamespace

    from nutribench.scheduler.driver import _Run

    events = [
        {"job_id": 1, "kind": "episode", "k": 2801, "k0": 2800, "ret": -3.0, "wall": 9800.0},
        {"job_id": 1, "kind": "phase", "phase": "eval"},  # says nothing of the resumed days
        {"job_id": 2, "kind": "episode", "k": 3, "k0": 0, "ret": None, "wall": None},
        {"job_id": 9, "kind": "episode", "k": 5, "k0": 4},  # not this run's: ignored
    ]
    run = _Run(None, None, [1, 2], None, SimpleNamespace(drain=lambda: events), None, "me", None)
    run.live = {1: {"k": 0, "ret": None}, 2: {"k": 0, "ret": None}}
    run.events()
    assert run.live[1] == {"k": 2801, "ret": -3.0, "wall": 9800.0} and run.live[2] == {"k": 3, "ret": None}
    assert run.resumed == {1: 2800, 2: 0}


def test_a_failed_batch_s_jobs_go_back_and_forget_their_resumed_days(monkeypatch) -> None:
    """A batch that fails is split and its jobs run again alone, from day 0: the days they
    had before this run no longer count against its ETA."""
    from concurrent.futures import Future
    from types import SimpleNamespace

    import nutribench.scheduler.driver as driver

    monkeypatch.setattr(driver, "release_jobs", lambda *a, **k: 2)
    run = driver._Run(None, None, [1, 2, 3], None, None, None, "me", SimpleNamespace(log=lambda m: None))
    run.resumed = {1: 2800, 2: 2800, 3: 100}
    failed: Future = Future()
    failed.set_exception(RuntimeError("out of memory"))
    specs = [SimpleNamespace(job_id=1), SimpleNamespace(job_id=2)]
    run._settle(failed, specs)  # type: ignore[arg-type]
    assert run.resumed == {3: 100} and run.pools[0].job_ids == [1, 2]


def test_progress_flushes_training_seconds_and_a_new_claim_clears_them(tmp_path: Path) -> None:
    from nutribench.scheduler.grid import Grid
    from nutribench.scheduler.lifecycle import claim_jobs, flush_progress, release_jobs
    from nutribench.scheduler.registration import load_grid_configs, register_grid
    from nutribench.store import open_store

    grid = Grid(("run0",), ("mc",), (0,), 4, 1)
    regimes, agents = load_grid_configs(grid)
    store = open_store(tmp_path / "p.db", writer=True)
    try:
        (job_id,) = register_grid(store, grid, regimes, agents)
        claim_jobs(store, [job_id], set(), 1, "me")
        flush_progress(store, "me", {job_id: {"k": 3, "ret": -1.0, "wall": 12.5}})
        with store.engine.connect() as c:
            assert c.execute(text("SELECT episodes_done, wall_seconds FROM jobs")).one() == (3, 12.5)
        release_jobs(store, [job_id], "me", "interrupted")
        with store.engine.connect() as c:
            assert c.execute(text("SELECT status, wall_seconds FROM jobs")).one() == ("interrupted", None)
        claim_jobs(store, [job_id], set(), 1, "me")
        with store.engine.connect() as c:
            assert c.execute(text("SELECT episodes_done, wall_seconds FROM jobs")).one() == (0, None)
    finally:
        store.dispose()


def test_bench_status_times_a_given_database(tmp_path: Path) -> None:
    from tests.conftest import benchmark_script

    bench_status = benchmark_script("status").bench_status

    db = tmp_path / "r.db"
    run_grid(
        GridSettings(
            db,
            ["run0", "run1"],
            ["ppo"],
            [0],
            episodes=4,
            eval_episodes=2,
            workers=1,
            job_fn=synthetic_job,
            models_dir=tmp_path / "m",
            display=False,
        )
    )
    r = bench_status(str(db), repeats=1)
    assert (r["jobs"], r["episode_rows"]) == (2, 2 * (4 + 2))
    assert r["build_seconds"] is None and r["status_table_s"] > 0 and r["status_cli_s"] > r["status_table_s"]


def test_status_prices_pending_jobs_by_their_algorithm_and_budget() -> None:
    from nutribench.scheduler.status import summarize

    def job(regime, algo, seed, budget, status, wall=None):  # the tuple status_table selects
        return (regime, 1, algo, 1, seed, budget, status, None, wall, 0, 0, None)

    jobs = [
        job("run0", "mc", 0, 100, "done", wall=10.0),
        job("run0", "ddqn", 0, 100, "done", wall=200.0),
        job("run1", "mc", 0, 100, "pending"),
        job("run1", "ddqn", 0, 100, "pending"),
        job("run1", "ddqn", 1, 100, "pending"),
        job("run1", "sac", 0, 400, "pending"),  # no done sac job: the mean rate of all, 1.05 s/day
    ]
    rep = summarize(jobs)
    left = {(r.regime, r.algo): r.remaining_seconds for r in rep.rows}
    assert left[("run1", "mc")] == pytest.approx(10.0)
    assert left[("run1", "ddqn")] == pytest.approx(400.0)
    assert left[("run1", "sac")] == pytest.approx(400 * (0.1 + 2.0) / 2)
    assert left[("run0", "mc")] == 0.0
    assert rep.eta_seconds == pytest.approx(10.0 + 400.0 + 420.0)  # nothing running: one worker


# --------------------------------------------------------------------------- the batched engine
@pytest.mark.slow
def test_engine_batched_trains_each_config_in_batches_and_stores_each_job(regimes: Path, tmp_path: Path) -> None:
    """--engine batched: each config's jobs run as batches (one per worker); every job is
    stored on its own with its engine; a batch that fails has its jobs
    tried one by one, so only the job that fails alone counts a failure; the next run, its
    cause fixed, completes it."""
    db, log = tmp_path / "r.db", tmp_path / "log"
    log.mkdir()
    env = dict(NUTRIBENCH_FAKE_LOG=str(log), fail="run3:ppo:1")
    args = dict(workers=2, job_fn=EnvJob(**env), batch_fn=EnvBatch(**env), display=False, engine="batched")
    s = run_grid(GridSettings(db, ["run0", "run3"], ["mc", "ppo", "sac"], [0, 1], 6, 1, **args))
    # 4 PPO jobs on 2 slots: batches of 2, in job order (run0 seeds 0,1; run3 seeds 0,1); the
    # batch holding the failing job fails, its two jobs are tried alone: one succeeds
    assert (s.done, s.failed) == (11, 1)
    rows = sql(
        db,
        "SELECT a.name, r.name, j.seed, j.status, j.engine FROM jobs j JOIN agent_configs a ON a.id = j.agent_config_id "
        "JOIN regimes r ON r.id = j.regime_id",
    )
    assert sorted((a, r, seed) for a, r, seed, st, _ in rows if st == "failed") == [("ppo", "run3", 1)]
    assert {(a, e) for a, _, _, st, e in rows if st == "done"} == {
        ("mc", "batched"),
        ("ppo", "batched"),
        ("sac", "batched"),
    }
    algo_of = dict(sql(db, "SELECT 'job' || j.id, a.name FROM jobs j JOIN agent_configs a ON a.id = j.agent_config_id"))
    pids: dict[str, set[str]] = {}
    for f in log.iterdir():  # job<id>-pid<pid>-<token>: one process per batch, one per single job
        job, pid, _ = f.name.split("-")
        pids.setdefault(algo_of[job], set()).add(pid)
    assert (len(pids["mc"]), len(pids["sac"])) == (2, 2)
    assert len(pids["ppo"]) == 4  # the good batch, the failed one, and its two jobs alone
    env["fail"] = ""  # its cause fixed
    args.update(job_fn=EnvJob(**env), batch_fn=EnvBatch(**env))
    s = run_grid(GridSettings(db, ["run0", "run3"], ["mc", "ppo", "sac"], [0, 1], 6, 1, **args))
    assert (s.done, s.failed, s.skipped) == (1, 0, 11)
    assert sql(db, "SELECT count(*) FROM jobs WHERE status = 'done'") == [(12,)]
    assert sql(db, "SELECT count(*) FROM episodes") == [(12 * 7,)]
    with pytest.raises(RunError, match="--engine 'fast'"):
        run_grid(GridSettings(db, ["run0"], ["ppo"], [0], 6, 1, engine="fast", job_fn=synthetic_job, display=False))


def test_batch_size_caps_the_batches(regimes: Path, tmp_path: Path) -> None:
    """--batch-size N: no batch holds more than N jobs (6 PPO jobs on 2 workers in batches of
    at most 2: 3 processes, not 2); 0 is refused before anything is written."""
    db, log = tmp_path / "r.db", tmp_path / "log"
    log.mkdir()
    env = dict(NUTRIBENCH_FAKE_LOG=str(log))
    s = run_grid(
        GridSettings(
            db,
            ["run0", "run3"],
            ["ppo"],
            [0, 1, 2],
            4,
            1,
            workers=2,
            job_fn=EnvJob(**env),
            batch_fn=EnvBatch(**env),
            display=False,
            engine="batched",
            max_batch=2,
        )
    )
    assert (s.done, s.failed) == (6, 0)
    pids = {f.name.split("-")[1] for f in log.iterdir()}
    assert len(pids) == 3
    with pytest.raises(RunError, match="--batch-size 0"):
        run_grid(
            GridSettings(
                tmp_path / "other.db", ["run0"], ["ppo"], [0], 4, 1, engine="batched", max_batch=0, display=False
            )
        )
    assert not (tmp_path / "other.db").exists()


@pytest.mark.slow
def test_engine_batched_with_real_training(regimes: Path, tmp_path: Path) -> None:
    """The batched engine's worker end to end: trained agents evaluated, saved, stored."""
    db = tmp_path / "r.db"
    s = run_grid(
        GridSettings(
            db,
            ["run0", "run3"],
            ["mc", "ppo"],
            [0],
            10,
            1,
            workers=2,
            display=False,
            engine="batched",
            models_dir=tmp_path / "models",
        )
    )
    assert (s.done, s.failed) == (4, 0)
    assert sql(db, "SELECT count(*), sum(engine = 'batched'), sum(model_path IS NOT NULL) FROM jobs") == [(4, 4, 4)]
    assert sql(db, "SELECT count(*) FROM eval_steps") == [(4 * 50,)]
    assert len(list((tmp_path / "models").rglob("*.zip"))) == 4
    # every row names the commit of the code that made it (this test runs in a git checkout)
    head = subprocess.run(
        ["git", "-C", str(Path(__file__).resolve().parents[1]), "rev-parse", "HEAD"],
        capture_output=True,
        text=True,
        check=True,
    ).stdout.strip()
    assert sql(db, "SELECT DISTINCT git_commit FROM jobs") == [(head,)]


def test_a_job_missing_from_its_batch_s_results_is_failed_not_left_running(regimes: Path, tmp_path: Path) -> None:
    db = tmp_path / "r.db"
    s = run_grid(
        GridSettings(
            db,
            ["run0"],
            ["ppo"],
            [0, 1, 2],
            4,
            1,
            workers=1,
            job_fn=synthetic_job,
            batch_fn=HalfBatch(),
            display=False,
            engine="batched",
        )
    )
    assert (s.done, s.failed) == (2, 1)
    assert sql(db, "SELECT status, count(*) FROM jobs GROUP BY status ORDER BY status") == [("done", 2), ("failed", 1)]
    assert "returned no result" in sql(db, "SELECT error FROM jobs WHERE status = 'failed'")[0][0]


def test_batches_group_jobs_by_config_and_regime_shape() -> None:
    from nutribench.scheduler.pools import batch_pools

    # "x": a config of an algorithm the batched engine does not train: its jobs run one by one
    cells = [("a", "ppo", 0), ("a", "ppo", 1), ("b", "ppo", 0), ("a", "x", 0), ("a", "mc", 0)]
    pools = batch_pools(
        [1, 2, 3, 4, 5],
        cells,
        {"ppo": "ppo", "x": "not_in_the_engine", "mc": "mc"},
        {"a": (50, 10), "b": (40, 10)},
        claimable=len,
        slots=2,
    )
    assert [(p.job_ids, p.batched, p.batch_size) for p in pools] == [
        ([1, 2], True, 1),
        ([3], True, 1),
        ([5], True, 1),
        ([4], False, 1),
    ]
