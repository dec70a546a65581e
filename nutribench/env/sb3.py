"""Stable-Baselines3 adapter: a :class:`NutriRLVectorEnv` seen as an SB3 ``VecEnv``.

Stable-Baselines3 trains directly on the natively batched env through this adapter (no
subprocesses, no per-env Python objects). Semantics follow SB3's ``DummyVecEnv``:
same-step autoreset, ``infos[j]["terminal_observation"]`` on the last step of a day.

The end of the day (step H) is reported as ``done`` *without* ``TimeLimit.truncated``:
nothing happens after step H (and time is not in the observation below level 2 of the
observation ladder), so learners must not bootstrap a value past it; the fixed-horizon day
is a true episode end. The observation space is the vector env's, at the regime's
observation level (:mod:`nutribench.env.nutri_env`: clock, pending amounts, schedule and
target included where the regime asks for them).

The batched info dict and the raw rewards of the last step are kept as ``last_info`` and
``last_rewards`` (arrays of length
``num_envs``), which is what :class:`~nutribench.env.metrics.EpisodeRecorder` reads.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode
from stable_baselines3.common.vec_env.base_vec_env import VecEnv, VecEnvIndices

from nutribench.env.vector_env import NutriRLVectorEnv


class NutriRLSB3VecEnv(VecEnv):
    """Wraps a ``NutriRLVectorEnv`` (built here if a regime is given) for SB3."""

    def __init__(self, venv: NutriRLVectorEnv | None = None, *, num_envs: int = 1, regime: Any = "run0"):
        if venv is None:
            venv = NutriRLVectorEnv(num_envs, regime=regime, autoreset_mode=AutoresetMode.SAME_STEP)
        if venv.metadata["autoreset_mode"] != AutoresetMode.SAME_STEP:
            raise ValueError("NutriRLSB3VecEnv needs a NutriRLVectorEnv with autoreset_mode=SAME_STEP")
        self.venv = venv
        # SB3's VecEnv takes its render_mode from the vector env's (None: it does not render)
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)
        self._actions: np.ndarray | None = None
        self.last_info: dict[str, Any] = {}
        self.last_rewards = np.zeros(self.num_envs)

    def reset(self):
        obs, info = self.venv.reset(seed=self._seeds[0], options=self._options[0] or None)
        self.last_info = info
        self.reset_infos = [{} for _ in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions: np.ndarray) -> None:
        self._actions = np.asarray(actions).reshape(self.num_envs)

    def step_wait(self):
        obs, rewards, terminated, truncated, info = self.venv.step(self._actions)
        self.last_info = info
        self.last_rewards = rewards
        dones = terminated | truncated
        # the env's info, env by env (what VecMonitor(info_keywords=...) and callbacks read);
        # at a day's end it is the day's last step's info, the next day's first obs aside
        per_env = [(k, v) for k, v in info.items() if k not in ("final_obs", "final_info")]
        infos: list[dict[str, Any]] = [{k: v[j] for k, v in per_env} for j in range(self.num_envs)]
        if dones.any():
            final_obs = info["final_obs"]
            for j in np.flatnonzero(dones):
                infos[j]["terminal_observation"] = final_obs[j]
        return obs, rewards.astype(np.float32), dones, infos

    def close(self) -> None:
        self.venv.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        value = getattr(self.venv, attr_name)
        return [value for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name: str, *method_args, indices: VecEnvIndices = None, **method_kwargs) -> list[Any]:
        result = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(self, wrapper_class, indices: VecEnvIndices = None) -> list[bool]:
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        return []
