"""The edges of issue 39 that need more than an argument list (tests/test_bad_input_harness.py
holds those): files with a byte that is not UTF-8, infinite hyperparameters, a full disk under
``regimes generate --write`` and under ``report``, a read-only database read by the read-only
commands. Each is one line and exit 2 with nothing half-written, or, for the read-only
database, simply works."""

from __future__ import annotations

import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from tests.conftest import one_error_line, run_cli_args
from tests.test_scheduler import regimes  # noqa: F401 - the fixture

runner = CliRunner()
FAKE = {"NUTRIBENCH_JOB": "fake"}


def files(folder: Path) -> set[Path]:
    return {p.relative_to(folder) for p in folder.rglob("*")}


# --------------------------------------------------------------------------- config files
@pytest.mark.parametrize(
    ("target", "command"),
    [
        ("run0.toml", ["regimes", "check"]),
        ("run0.toml", ["regimes", "list"]),
        ("run0.toml", "run"),
        ("agents/ppo.toml", "run"),
        ("foods.toml", ["regimes", "check", "--regimes", "run1"]),
    ],
)
def test_a_config_file_with_a_byte_that_is_not_utf8_is_one_line_naming_file_and_line(
    regimes, tmp_path, target, command
):
    """A regime or agent file with a Latin-1 byte was a UnicodeDecodeError traceback."""
    path = regimes / target
    path.write_bytes(path.read_bytes() + b"# caf\xe9\n")
    line_no = path.read_bytes().count(b"\n")
    db = tmp_path / "r.db"
    args = run_cli_args(db, episodes=2) if command == "run" else command
    line = one_error_line(runner.invoke(app, args, env=FAKE))
    assert f"{path}: line {line_no}: byte 0xe9 is not UTF-8" in line and "save the file as UTF-8" in line, line
    assert not db.exists()


@pytest.mark.parametrize(
    ("field", "value"),
    [("learning_rate", "inf"), ("learning_rate", "nan"), ("ent_coef", "inf"), ("clip_range", "+inf")],
)
def test_an_infinite_hyperparameter_is_refused_before_the_database(regimes, tmp_path, field, value):
    """``learning_rate = inf`` trained, and the job was stored as done."""
    path = regimes / "agents" / "ppo.toml"
    text = path.read_text()
    lines = [f"{field} = {value}" if ln.split("=")[0].strip() == field else ln for ln in text.splitlines()]
    assert lines != text.splitlines()
    path.write_text("\n".join(lines) + "\n")
    db = tmp_path / "r.db"
    line = one_error_line(runner.invoke(app, run_cli_args(db, episodes=2), env=FAKE))
    assert f"ppo.toml: {field}: Input should be a finite number" in line, line
    assert not db.exists()


@pytest.mark.parametrize("target", ["agents/ddqn.toml", "run0.toml"])
def test_a_config_version_too_large_for_the_database_is_refused_before_it(regimes, tmp_path, target):
    """Found by the fuzz harness: ``version = 9223372036854775808`` was an OverflowError when stored."""
    path = regimes / target
    path.write_text(path.read_text().replace("version = ", "version = 9223372036854775808  # was ", 1))
    db = tmp_path / "r.db"
    line = one_error_line(runner.invoke(app, run_cli_args(db, algos="ddqn", episodes=2), env=FAKE))
    assert f"{target.split('/')[-1]}: version: Input should be less than or equal to 2147483647" in line, line
    assert not db.exists()


def test_an_infinite_gradient_norm_still_means_no_clipping():
    """The one float that may be inf: Table 2's MC has no gradient clipping (max_grad_norm = inf)."""
    from nutribench.agents.config import load_agent_config, parse_agent_config

    assert load_agent_config("mc").max_grad_norm == float("inf")
    body = load_agent_config("ppo").model_dump(mode="json")
    assert parse_agent_config({**body, "max_grad_norm": float("inf")}).max_grad_norm == float("inf")


# --------------------------------------------------------------------------- a full disk
def _full_disk_open(real_open):
    """``open`` whose files take no byte: a write raises ENOSPC (the file itself is created, as on a full disk)."""

    class Full:
        def __init__(self, fh):
            self.fh = fh

        def write(self, _data):
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

        def __getattr__(self, name):
            return getattr(self.fh, name)

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.fh.close()

    return lambda *a, **k: Full(real_open(*a, **k))


def test_regimes_generate_on_a_full_disk_leaves_no_file_and_a_retry_works(regimes, monkeypatch):
    """It left an empty run8.toml that then blocked the name (exists: --force) and hid it
    (an empty file is no regime). Now the write goes to a temporary file renamed at the end."""
    import nutribench.config.generate as generate

    args = ["regimes", "generate", "run8", "--from", "run6", "--tau", "C=10-12", "--write"]
    before = files(regimes)
    monkeypatch.setattr(generate, "open", _full_disk_open(open), raising=False)
    line = one_error_line(runner.invoke(app, args))
    assert f"cannot write {regimes / 'run8.toml'}: No space left on device: nothing was written" in line, line
    assert files(regimes) == before  # no run8.toml, no temporary file
    monkeypatch.undo()
    res = runner.invoke(app, args, env={"NUTRIBENCH_REGIMES": str(regimes)})
    assert res.exit_code == 0, res.output
    assert "run8" in runner.invoke(app, ["regimes", "list"], env={"NUTRIBENCH_REGIMES": str(regimes)}).output


def test_a_report_that_meets_a_full_disk_is_one_line_and_leaves_no_partial_file(tmp_path, monkeypatch):
    """A table's second file meets a full disk: one line, exit 2, the first file whole, no temporary file."""
    from types import SimpleNamespace

    from nutribench.report import output
    from nutribench.report.data import ReportError

    table = SimpleNamespace(to_markdown=lambda: "| a |", to_latex=lambda: "a", to_csv=lambda: "a\n")
    real = Path.write_text
    calls = []

    def write_text(self, *a, **k):
        calls.append(self)
        if len(calls) == 2:
            real(self, "half")  # a partial write, then the disk is full
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        return real(self, *a, **k)

    monkeypatch.setattr(Path, "write_text", write_text)
    with pytest.raises(ReportError, match=r"cannot write .*table\.tex: No space left on device"):
        output.write_table(table, tmp_path / "out", "table")
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["table.md"]


# --------------------------------------------------------------------------- a read-only database
#: runs each argv (a JSON list of lists) in process and prints [[exit code, output], ...]
_INVOKE = """
import json, sys
from typer.testing import CliRunner
from nutribench.cli import app
print(json.dumps([(r.exit_code, r.output) for r in (CliRunner().invoke(app, a) for a in json.loads(sys.argv[1]))]))
"""


def _as_read_only(folder: Path, argvs: list[list[str]], cwd: Path) -> list[tuple[int, str]]:
    """Each ``nutribench argv`` run, in one process, where ``folder`` is read-only: a read-only
    bind mount in a user namespace when this process is root (root writes any file whatever
    its mode), else the folder and its files without write permission."""
    import json

    cmd = [sys.executable, "-c", _INVOKE, json.dumps(argvs)]
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(sys.path))
    if os.geteuid() != 0:
        for p in folder.iterdir():
            p.chmod(0o444)
        folder.chmod(0o555)
        try:
            res = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)
        finally:
            folder.chmod(0o755)
    else:
        if shutil.which("unshare") is None or subprocess.run(["unshare", "-r", "-m", "true"]).returncode != 0:
            pytest.fail("as root the test needs `unshare -r -m` (user namespaces) to make a folder read-only")
        script = f'mount --bind "{folder}" "{folder}" && mount -o remount,ro,bind "{folder}" && exec "$@"'
        res = subprocess.run(
            ["unshare", "-r", "-m", "sh", "-c", script, "sh", *cmd],
            cwd=cwd,
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
    assert res.returncode == 0, res.stderr
    return [tuple(r) for r in json.loads(res.stdout.splitlines()[-1])]


@pytest.mark.slow  # a dry run, then a subprocess that imports the report: about 25 s on a busy machine
def test_a_read_only_database_is_read_by_the_read_only_commands(regimes, tmp_path):
    """``status``, ``report`` and ``db export`` on a database in a read-only folder failed with
    "cannot open database ...: unable to open database file" (SQLite wants to create the WAL's
    shared-memory file beside it); they now open it read-only. ``run`` still refuses it in one line."""
    lab = tmp_path / "lab"
    lab.mkdir()
    assert runner.invoke(app, run_cli_args(lab / "r.db", episodes=2), env=FAKE).exit_code == 0
    shutil.rmtree(lab / "models")
    before = {p: p.read_bytes() for p in lab.iterdir()}
    argvs = [
        ["status", "--db", "lab/r.db"],
        ["db", "export", str(tmp_path / "out.npz"), "--db", "lab/r.db"],
        ["report", "--table", "results", "--db", "lab/r.db", "--out", str(tmp_path / "rep")],
        run_cli_args(Path("lab/r.db"), episodes=2, seeds="1"),
    ]
    status, export, report, run = _as_read_only(lab, argvs, tmp_path)
    for _, out in (status, export, report, run):
        assert "Traceback" not in out and "unable to open" not in out, out
    assert status[0] == 0 and "1 job: 1 done" in status[1].replace("\n", " "), status
    assert export[0] == 0 and (tmp_path / "out.npz").is_file(), export
    assert report[0] == 2 and "holds no finished episodes yet" in report[1], report  # read: a dry run is no report
    assert run[0] == 2 and run[1].startswith("error:"), run  # a writer is refused in one line
    assert {p: p.read_bytes() for p in lab.iterdir()} == before


# --------------------------------------------------------------------------- the run's summary
@pytest.mark.parametrize("stops", ["while it runs the others", "while it waits"])
def test_the_progress_after_a_takeover_counts_the_jobs_taken_over(regimes, tmp_path, monkeypatch, stops):
    """A run that takes over a crashed driver's job said "3 done, ... of 2 to run": the jobs to
    run were counted once, at its start. Those it takes over are its own to run from then on,
    whether the job goes stale while the run still has others to claim (a claim takes it with
    them: issue 53, which a heartbeat set to go stale a second later hit only on a busy machine)
    or while the run waits for it. The stale rule reads a clock the test moves, not the wall's."""
    from datetime import timedelta

    from sqlalchemy import create_engine, text

    from nutribench.scheduler import driver, lifecycle
    from nutribench.scheduler.driver import GridSettings, run_grid
    from nutribench.scheduler.synthetic import synthetic_job
    from nutribench.store.engine import utcnow
    from nutribench.store.models import STALE_AFTER_S

    db = tmp_path / "r.db"
    assert (
        run_grid(
            GridSettings(db, ["run0"], ["ppo"], [0, 1, 2], 2, 1, workers=1, job_fn=synthetic_job, display=False)
        ).done
        == 3
    )
    t0 = utcnow()
    clock = {"now": t0}  # the database's clock, as the driver's lifecycle reads it
    monkeypatch.setattr(lifecycle, "db_now", lambda conn: clock["now"])
    engine = create_engine(f"sqlite:///{db}")
    with engine.begin() as conn:  # seeds 0 and 1 to run, seed 2 held by a driver alive at t0
        for table in ("episodes", "eval_steps"):
            conn.execute(text(f"DELETE FROM {table}"))
        conn.execute(text("UPDATE jobs SET status='pending', owner=NULL WHERE seed < 2"))
        conn.execute(
            text("UPDATE jobs SET status='running', owner='crashed', heartbeat_at=:b WHERE seed = 2"), {"b": t0}
        )
    engine.dispose()

    def heartbeat_stops() -> None:
        clock["now"] = t0 + timedelta(seconds=STALE_AFTER_S + 1)

    if stops == "while it runs the others":  # once the run claimed seed 0: its next claims take seed 1, then seed 2
        claim = driver.claim_jobs

        def claim_then_stop(*args, **kwargs):
            jobs = claim(*args, **kwargs)
            if jobs:
                heartbeat_stops()
            return jobs

        monkeypatch.setattr(driver, "claim_jobs", claim_then_stop)
    else:  # once seeds 0 and 1 are done and the run waits for seed 2
        wait = driver._Run.wait_for_others

        def stop_then_wait(run):
            heartbeat_stops()
            return wait(run)

        monkeypatch.setattr(driver._Run, "wait_for_others", stop_then_wait)
    res = runner.invoke(app, run_cli_args(db, "--workers", "1", seeds="0,1,2", episodes=2), env=FAKE)
    out = " ".join(res.output.split())
    assert res.exit_code == 0, res.output
    assert "2 of 3 jobs to run" in out and "jobs: 3 done, 0 failed, 0 running, of 3 to run (grid 3)" in out, out


@pytest.mark.parametrize("value", ["[]", "{ x = 1 }", "3"])
def test_an_agent_file_whose_algo_is_not_a_name_is_one_line(regimes, tmp_path, value):
    """Found by the fuzz harness: ``algo = []`` was a TypeError (unhashable type: 'list')."""
    path = regimes / "agents" / "ddqn.toml"
    path.write_text(path.read_text().replace('algo = "ddqn"', f"algo = {value}", 1))
    line = one_error_line(runner.invoke(app, run_cli_args(tmp_path / "r.db", algos="ddqn", episodes=2), env=FAKE))
    assert "ddqn.toml: algo: unknown algorithm" in line, line
    assert not (tmp_path / "r.db").exists()


@pytest.mark.parametrize(
    ("option", "value"),
    [
        ("--episode", "1000000000000000000000000000000"),
        ("--episode", str(2**63)),
        ("--episode", str(2**31)),
        ("--seed", "1000000000000000000000000000000"),
        ("--seed", "-1"),
    ],
)
def test_a_trajectory_number_past_the_database_integer_is_one_line(regimes, tmp_path, option, value):
    """Issue 52: ``report --trajectory --episode 1000000000000000000000000000000`` was an
    OverflowError traceback (the number met the database's integer in the query)."""
    from nutribench.scheduler.driver import GridSettings, run_grid
    from nutribench.scheduler.synthetic import synthetic_job

    db = tmp_path / "r.db"
    assert (
        run_grid(GridSettings(db, ["run0"], ["ppo"], [0], 2, 1, workers=1, job_fn=synthetic_job, display=False)).done
        == 1
    )
    picked = {"--seed": "0", "--episode": "0", option: value}
    args = [
        "report",
        "--trajectory",
        "--algo",
        "ppo",
        "--regime",
        "run0",
        "--db",
        str(db),
        "--out",
        str(tmp_path / "o"),
    ]
    line = one_error_line(runner.invoke(app, [*args, "--seed", picked["--seed"], "--episode", picked["--episode"]]))
    assert line.startswith(f"error: {option} {value[:24]}: give a value from 0 to "), line
    assert not (tmp_path / "o").exists()
