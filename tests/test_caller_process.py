"""A library does not change its caller's process (issue 53): training leaves torch's thread
count and the warnings filters as they were, opening a study's storage leaves the filters, and
a plug-in import leaves ``sys.path`` as it was when it fails."""

from __future__ import annotations

import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

import pytest
import torch as th

import nutribench  # noqa: F401 (what importing it does is part of what is checked)
from nutribench.agents import train
from nutribench.agents.config import load_agent_config
from nutribench.agents.registry import EntryPointError, import_entry_point
from nutribench.config.loading import ConfigError
from nutribench.engine.train import train_batched

CALLER_THREADS = 2  # not the 1 training runs on, so that a count left changed shows


@pytest.fixture
def caller_threads() -> Iterator[int]:
    """torch on :data:`CALLER_THREADS` threads while the test runs; the count before, afterwards."""
    before = th.get_num_threads()
    th.set_num_threads(CALLER_THREADS)
    yield CALLER_THREADS
    th.set_num_threads(before)


@pytest.fixture
def filters() -> list:
    """The warnings filters before the test's calls (torch imports ``torch._dynamo`` on the first
    optimiser step, and sympy with it, which adds a filter of its own: imported first here)."""
    import torch._dynamo  # noqa: F401

    return list(warnings.filters)


def test_training_leaves_the_threads_and_the_warnings_filters(caller_threads: int, filters: list) -> None:
    train("run0", "ppo", seed=0, episodes=1)
    assert (th.get_num_threads(), warnings.filters) == (caller_threads, filters)


def test_batched_training_leaves_the_threads_and_the_warnings_filters(caller_threads: int, filters: list) -> None:
    train_batched([("run3", 7)], load_agent_config("ppo"), 1)
    assert (th.get_num_threads(), warnings.filters) == (caller_threads, filters)


def test_a_training_that_fails_restores_the_threads(caller_threads: int) -> None:
    with pytest.raises(ConfigError):
        train("no-such-regime", "ppo", seed=0, episodes=1)
    assert th.get_num_threads() == caller_threads


def test_opening_a_study_storage_leaves_the_warnings_filters(tmp_path: Path) -> None:
    from nutribench.tuning.study import optuna_storage

    filters = list(warnings.filters)
    assert optuna_storage(f"sqlite:///{tmp_path / 'lab.db'}") is not None
    assert warnings.filters == filters


@pytest.mark.parametrize(
    "plugin",
    [
        None,  # no such module, here or installed
        "import nbtest_no_such_dependency\n",  # beside the user's scripts, its own import failing
        "raise RuntimeError('broken plug-in')\n",  # beside the user's scripts, failing on import
    ],
)
def test_a_failed_plugin_import_leaves_sys_path(tmp_path: Path, monkeypatch, plugin: str | None) -> None:
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", list(sys.path))  # whatever happens, undone afterwards
    if plugin is not None:
        (tmp_path / "nbtest_broken_plugin.py").write_text(plugin)
    path = list(sys.path)
    with pytest.raises((EntryPointError, RuntimeError)):
        import_entry_point("nbtest_broken_plugin:make_agent")
    assert sys.path == path


def test_a_plugin_beside_the_scripts_keeps_its_folder_on_sys_path(tmp_path: Path, monkeypatch) -> None:
    """As under ``python -m``: a plug-in found in the current folder may import its neighbours later."""
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", list(sys.path))
    (tmp_path / "nbtest_good_plugin.py").write_text("def make_agent(params, env, seed):\n    return None\n")
    try:
        assert callable(import_entry_point("nbtest_good_plugin:make_agent"))
    finally:
        sys.modules.pop("nbtest_good_plugin", None)
    assert sys.path[-1] == str(tmp_path)


# --------------------------------------------------------------------------- issue 72
def _running(db: Path) -> bool:
    from sqlalchemy import create_engine, text

    if not db.exists():
        return False
    engine = create_engine(f"sqlite:///{db}")
    try:
        with engine.connect() as conn:
            has_jobs = conn.execute(text("SELECT count(*) FROM sqlite_master WHERE name = 'jobs'")).scalar()
            return bool(has_jobs) and bool(
                conn.execute(text("SELECT count(*) FROM jobs WHERE status = 'running' AND episodes_done > 0")).scalar()
            )
    finally:
        engine.dispose()


@pytest.fixture
def ctrl_c_raises() -> Iterator[None]:
    """SIGINT as a plain Python program has it (pytest's workers may differ); put back afterwards."""
    import signal

    before = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, before)


def test_run_grid_installs_no_signal_handler_and_a_second_ctrl_c_still_interrupts(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ctrl_c_raises: None
) -> None:
    """run_grid in-process: a stop event and then a Ctrl-C each stop a run (its running job
    released as interrupted); the caller's handlers are as they were, and the next Ctrl-C
    interrupts the caller (it used to be ignored until exit: a notebook interrupted once could
    not be interrupted again)."""
    import os
    import signal
    import threading
    import time

    from nutribench.scheduler.driver import GridSettings, run_grid
    from tests.conftest import wait_for
    from tests.fake_jobs import EnvJob

    monkeypatch.delenv("NUTRIBENCH_AGENTS", raising=False)
    monkeypatch.delenv("NUTRIBENCH_REGIMES", raising=False)
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    db = tmp_path / "r.db"
    job = EnvJob(NUTRIBENCH_FAKE_SECONDS="0.05")
    args = dict(seeds=[0], episodes=400, eval_episodes=1, workers=1, job_fn=job, display=False)

    stop = threading.Event()
    setter = threading.Thread(target=lambda: (wait_for(lambda: _running(db), 120), stop.set()), daemon=True)
    setter.start()
    summary = run_grid(GridSettings(db, ["run0"], ["ppo"], **args), stop=stop)
    setter.join()
    assert (summary.user_interrupt, summary.interrupted, summary.exit_code) == (True, 1, 130)

    def ctrl_c() -> None:
        wait_for(lambda: _running(db), 120)
        os.kill(os.getpid(), signal.SIGINT)

    threading.Thread(target=ctrl_c, daemon=True).start()
    summary = run_grid(GridSettings(db, ["run0"], ["ppo"], **args))
    assert (summary.user_interrupt, summary.interrupted) == (True, 1)
    assert {sig: signal.getsignal(sig) for sig in handlers} == handlers
    with pytest.raises(KeyboardInterrupt):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(5)


def test_a_job_in_the_caller_s_process_leaves_its_threads_and_environment(
    caller_threads: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What every executor runs (:func:`~nutribench.scheduler.worker.execute`) sets one thread of
    torch and BLAS while the job runs, then puts the caller's back (an executor of threads runs
    it in the caller's own process)."""
    import os

    from nutribench.scheduler.worker import THREAD_VARIABLES, execute

    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setenv("MKL_NUM_THREADS", "3")
    monkeypatch.delenv("OPENBLAS_NUM_THREADS", raising=False)
    before = {var: os.environ.get(var) for var in THREAD_VARIABLES}
    seen = {}

    def job(spec, sink):
        seen.update({var: os.environ.get(var) for var in THREAD_VARIABLES}, threads=th.get_num_threads())
        return "result"

    assert execute(job, None) == "result"
    assert seen == {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "3", "OPENBLAS_NUM_THREADS": "1", "threads": 1}
    assert {var: os.environ.get(var) for var in THREAD_VARIABLES} == before
    assert th.get_num_threads() == caller_threads


def test_a_failing_job_in_the_caller_s_process_leaves_its_threads(caller_threads: int) -> None:
    from nutribench.scheduler.worker import JobFailed, execute

    def job(spec, sink):
        raise ValueError("broken")

    with pytest.raises(JobFailed, match="ValueError: broken"):
        execute(job, None)
    assert th.get_num_threads() == caller_threads


def test_the_matmul_rate_leaves_the_threads(caller_threads: int) -> None:
    from nutribench.bench.throughput import matmul_flops_per_s

    assert matmul_flops_per_s(k=2, batch=4, n_in=8, n_out=8, repeats=2) > 0
    assert th.get_num_threads() == caller_threads


def test_a_refused_checkpoint_is_a_logged_warning_on_stderr_where_logging_is_not_set_up(tmp_path: Path) -> None:
    """Library messages go through ``logging`` (a caller may route or silence them); a worker
    process, which sets up no logging, still says the one line on stderr."""
    import subprocess

    path = tmp_path / "batch.pt"
    path.write_bytes(b"not a checkpoint")
    code = (
        "import sys\nfrom nutribench.engine.checkpoint import Checkpoint\n"
        "assert Checkpoint(sys.argv[1]).state is None\n"
        "import logging\nassert logging.getLogger().handlers == []\n"
    )
    result = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    (line,) = result.stderr.splitlines()
    assert line.startswith(f"nutribench: {path}: checkpoint refused (") and line.endswith("; the batch starts over")


def _calls(tree, module: str, attribute: str) -> list[int]:
    import ast

    return [
        node.lineno
        for node in ast.walk(tree)
        if isinstance(node, ast.Call)
        and isinstance(node.func, ast.Attribute)
        and node.func.attr == attribute
        and isinstance(node.func.value, ast.Name)
        and node.func.value.id == module
    ]


def test_signal_handlers_are_set_only_by_the_command_line_and_no_library_code_kills_its_process() -> None:
    import ast

    root = Path(__file__).resolve().parents[1]
    found = []
    for path in sorted((root / "nutribench").rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        tree = ast.parse(path.read_text(encoding="utf-8"))
        if not rel.startswith("nutribench/cli/"):  # not even a worker's main: workers leave the terminal's group
            found += [f"{rel}:{n} signal.signal" for n in _calls(tree, "signal", "signal")]
        found += [f"{rel}:{n} os.kill" for n in _calls(tree, "os", "kill")]
    assert found == []
