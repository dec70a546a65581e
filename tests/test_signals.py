"""Stop signals: any number of SIGINT / SIGTERM / SIGHUP end in the one
graceful stop the first began, and ``nutribench run`` exits 130 with its running jobs
released as interrupted and no row half-written (a second SIGTERM or SIGHUP during the stop
used to kill the driver by the signal: exit 143 / 129)."""

from __future__ import annotations

import signal
import subprocess
import time
from pathlib import Path

import pytest

from nutribench.cli.run import STOP_SIGNALS
from tests.conftest import run_cli_args, wait_for
from tests.test_scheduler import NUTRIBENCH, _env, regimes, sql, statuses  # noqa: F401 - regimes: the fixture


def _default_stop_signals() -> None:
    for sig in STOP_SIGNALS:
        signal.signal(sig, signal.SIG_DFL)


@pytest.mark.slow
@pytest.mark.serial
@pytest.mark.parametrize(
    ("first", "then"),
    [
        (signal.SIGTERM, signal.SIGTERM),
        (signal.SIGTERM, signal.SIGHUP),
        (signal.SIGHUP, signal.SIGHUP),
        (signal.SIGINT, signal.SIGTERM),
        (signal.SIGINT, signal.SIGINT),
    ],
    ids=lambda s: s.name,
)
def test_signals_during_the_graceful_stop_end_in_that_stop_and_exit_130(
    regimes: Path, tmp_path: Path, first, then
) -> None:
    db = tmp_path / "r.db"
    cmd = [
        NUTRIBENCH,
        *run_cli_args(db, "--workers", "2", algos="ppo,sac", seeds="0,21", episodes=400, eval_episodes=2),
    ]
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
            timeout=120,  # a precondition (workers started, torch imported): as test_scheduler's Ctrl-C test
        )
        proc.send_signal(first)
        sent, end = 1, time.monotonic() + 30
        while proc.poll() is None and time.monotonic() < end:  # the stop meets signal after signal until it is over
            proc.send_signal(then)
            sent += 1
            time.sleep(0.005)
        out, _ = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert sent > 1
    assert proc.returncode == 130, (proc.returncode, out)
    assert "Traceback" not in out and "2 interrupted" in out, out
    assert sorted(statuses(db).values()) == ["interrupted", "interrupted", "pending", "pending"]
    assert sql(db, "SELECT count(*) FROM episodes")[0][0] == 0
    assert sql(db, "SELECT count(*) FROM eval_steps")[0][0] == 0
    assert sql(db, "SELECT count(*) FROM jobs WHERE owner IS NOT NULL")[0][0] == 0
