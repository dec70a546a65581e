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
