"""A nutribench DDQN loads with plain SB3's ``DQN.load`` without the false warning that
``n_steps=5`` "is ignored" (issue 75): the buffer class SB3 chose from ``n_steps`` is no
longer saved, so SB3 chooses it again on load; a file saved before loads quietly through
``DoubleDQN.load``. Either way the loaded model's buffer computes 5-step returns."""

from __future__ import annotations

import warnings
from pathlib import Path

import gymnasium as gym
import pytest
from stable_baselines3 import DQN
from stable_baselines3.common.buffers import NStepReplayBuffer

import nutribench  # noqa: F401 (registers the environments)
from nutribench.agents.builtin.ddqn import DoubleDQN


def _model() -> DoubleDQN:
    return DoubleDQN(
        "MlpPolicy", gym.make("nutribench/NutriRL-run0-v0"), n_steps=5, learning_starts=10, buffer_size=500
    )


def test_plain_dqn_load_of_a_nutribench_ddqn_is_quiet_and_keeps_five_step_returns(tmp_path: Path):
    path = tmp_path / "ddqn.zip"
    _model().save(path)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for cls in (DQN, DoubleDQN):
            model = cls.load(path)
            assert isinstance(model.replay_buffer, NStepReplayBuffer)
            assert (model.n_steps, model.replay_buffer.n_steps, model.replay_buffer.gamma) == (5, 5, 0.99)


def test_a_file_saved_with_its_buffer_class_loads_quietly_through_double_dqn(tmp_path: Path):
    path = tmp_path / "old.zip"
    model = _model()
    # as files were saved before: the buffer class with the rest
    model._excluded_save_params = lambda: [  # type: ignore[method-assign]
        p for p in DQN._excluded_save_params(model) if p != "replay_buffer_class"
    ]
    model.save(path)
    with pytest.warns(UserWarning, match="n_steps=5` is ignored"):
        DQN.load(path)  # SB3's own warning, still there for plain SB3 on such a file (docs/agents.md)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = DoubleDQN.load(path)
    assert isinstance(loaded.replay_buffer, NStepReplayBuffer) and loaded.replay_buffer.n_steps == 5
