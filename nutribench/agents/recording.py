"""How a training day is recorded: :class:`EpisodeMetrics` (the SB3 callback of the built-in
algorithms) and :class:`RecordingVecEnv` (the env of a plug-in agent, whatever its ``learn``
does); both read the NutriRL adapter's raw rewards and info, not what ``VecNormalize`` scaled."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.vec_env import VecEnv, VecEnvWrapper

from nutribench.agents.algos import episode_entropy
from nutribench.env.metrics import EpisodeRecorder
from nutribench.env.sb3 import NutriRLSB3VecEnv

EpisodeFn = Callable[[dict[str, Any]], None]


def finish_day(
    days: list[dict[str, Any]], metrics: dict[str, Any], model: Any, obs: list, on_episode: EpisodeFn | None
) -> None:
    """Append a finished day's row (its number, ``metrics`` and the entropy of ``model``'s policy
    over the day's observations ``obs``, None without a model) to ``days``, hand it to
    ``on_episode``, and forget ``obs``."""
    entropy = episode_entropy(model, np.stack(obs)) if model is not None else None
    obs.clear()
    days.append({"episode": len(days), **metrics, "entropy": entropy})
    if on_episode is not None:
        on_episode(days[-1])


class EpisodeMetrics(BaseCallback):
    """Records the per-day metrics (:data:`~nutribench.env.metrics.METRIC_KEYS`) of every
    finished training day and stops after ``episodes``.

    Reads the dones SB3 passes to callbacks and the raw rewards and batched info of the
    NutriRL SB3 adapter (not SB3's rewards, which ``VecNormalize`` may have scaled); the observation each action was taken at is ``model._last_obs``
    during ``on_step`` (on- and off-policy SB3 update it after the callback).
    """

    def __init__(self, base_env: NutriRLSB3VecEnv, episodes: int, on_episode: EpisodeFn | None = None):
        super().__init__()
        self.base_env, self.n_episodes, self.on_episode = base_env, episodes, on_episode
        self.recorder = EpisodeRecorder(1)
        self.episodes: list[dict[str, Any]] = []
        self._obs: list[np.ndarray] = []

    def _on_step(self) -> bool:
        self._obs.append(np.array(self.model._last_obs[0], dtype=np.float32))
        for metrics in self.recorder.record(self.base_env.last_rewards, self.locals["dones"], self.base_env.last_info):
            finish_day(self.episodes, metrics, self.model, self._obs, self.on_episode)
        return len(self.episodes) < self.n_episodes or self._rollout_ends_here()

    def _rollout_ends_here(self) -> bool:
        """True on the last step of an on-policy rollout: there, stopping would make SB3 drop
        the rollout without its update, so training goes on and ``learn`` ends after the
        update (``total_timesteps`` is the budget). A budget that ends mid-rollout stops there:
        SB3 cannot update on a partial rollout, so those last days teach nothing."""
        n, n_rollout = self.locals.get("n_steps"), self.locals.get("n_rollout_steps")
        return isinstance(self.model, OnPolicyAlgorithm) and n is not None and n + 1 == n_rollout


class RecordingVecEnv(VecEnvWrapper):
    """The training env of a plug-in agent: records the per-day metrics of its first
    ``episodes`` finished days, whatever its ``learn`` does (no SB3 callback needed).

    Sits outside ``VecNormalize``, so the observations it keeps for the day's entropy are the
    ones the policy saw; the metrics are read from the NutriRL adapter's raw rewards and info.
    """

    def __init__(self, venv: VecEnv, base: NutriRLSB3VecEnv, episodes: int, on_episode: EpisodeFn | None = None):
        super().__init__(venv)
        self.base, self.n_episodes, self.on_episode = base, episodes, on_episode
        self.model: Any = None
        self.recorder = EpisodeRecorder(1)
        self.episodes: list[dict[str, Any]] = []
        self._obs: list[np.ndarray] = []

    def reset(self) -> np.ndarray:
        obs = self.venv.reset()
        self.recorder.clear()
        self._obs = [np.array(obs[0], dtype=np.float32)]
        return obs

    def step_wait(self) -> Any:
        obs, rewards, dones, infos = self.venv.step_wait()
        for metrics in self.recorder.record(self.base.last_rewards, dones, self.base.last_info):
            if len(self.episodes) < self.n_episodes:
                finish_day(self.episodes, metrics, self.model, self._obs, self.on_episode)
            self._obs.clear()
        self._obs.append(np.array(obs[0], dtype=np.float32))
        return obs, rewards, dones, infos

    def check_budget(self, cfg: Any) -> None:
        """A plug-in's ``learn(total_timesteps=days x horizon)`` must play its whole budget."""
        if len(self.episodes) < self.n_episodes:
            raise RuntimeError(
                f"{cfg.entry_point}: learn() played {len(self.episodes)} whole days of the {self.n_episodes} asked "
                "(it must honour total_timesteps)"
            )
