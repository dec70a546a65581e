"""A natively batched NutriRL: ``num_envs`` independent days stepped with numpy at once.

Per-env semantics are exactly those of :class:`~nutribench.env.NutriRLEnv` (tests check
that N single envs fed the same foods and actions give the same observations, rewards and
infos, at every level of the observation ladder: both fill the rungs above level 1 with
:meth:`~nutribench.env.nutri_env.RegimeDynamics.write_extras`). All envs share the fixed horizon and never terminate early, so they are always at
the same step and end together; the autoreset then resets all of them at once.

Autoreset mode (``metadata["autoreset_mode"]``, chosen by the ``autoreset_mode`` argument):

* ``NEXT_STEP`` (default, Gymnasium's convention and the one its vector wrappers accept):
  the step after the final one resets every env, ignores the actions and returns reward 0;
* ``SAME_STEP`` (what Stable-Baselines3 expects): the final step returns the first
  observation of the next day and puts the last one in ``info["final_obs"]``.

Randomness: one generator (``self.np_random``, seeded by ``reset(seed=)``) draws the food
streams of all envs, one ``(num_envs, H)`` draw per day, so env j does not reproduce a
single env seeded with ``seed + j``; pass ``options={"foods": ...}`` to fix the streams.

Infos are dicts of arrays of length ``num_envs`` (``overshoot`` is ``(num_envs, 3)``).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from nutribench.config import EnvConfig
from nutribench.env.nutri_env import DynamicsView, RegimeDynamics


class NutriRLVectorEnv(DynamicsView, VectorEnv):
    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        regime: str | os.PathLike[str] | EnvConfig = "run0",
        autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
        render_mode: str | None = None,
    ):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        if render_mode is not None:
            raise ValueError("the vector env does not render; render a single NutriRLEnv")
        mode = AutoresetMode(autoreset_mode) if isinstance(autoreset_mode, str) else autoreset_mode
        if mode not in (AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP):
            raise ValueError(f"autoreset_mode must be NEXT_STEP or SAME_STEP, got {mode}")
        self.metadata = {**self.metadata, "autoreset_mode": mode}
        self.dyn = RegimeDynamics(regime)
        self.num_envs = num_envs
        self.render_mode = None
        self.single_observation_space = self.dyn.observation_space
        self.single_action_space = self.dyn.action_space
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.action_space = batch_space(self.single_action_space, num_envs)
        self._lp, self._lc, self._lo, self._tau_c = self.dyn.coefficients
        H, N = self.dyn.horizon, self.dyn.n_foods
        self._H, self._N = H, N
        # Nutrient-major layouts (rows = step x nutrient, columns = envs) keep every per-step
        # slice contiguous. _A2T[3k + n, i]: food i's nutrient n absorbed k steps after eating,
        # so eating is one matrix product of a prefix of it with the (eat x one-hot) columns.
        self._A2T = np.ascontiguousarray(self.dyn.schedule.reshape(N, H * 3).T)
        self._pending = np.zeros((H * 3, num_envs))
        self._tmp = np.empty((H * 3, num_envs))
        self._s = np.zeros((3, num_envs))
        self._d = np.full(num_envs, 3.0)
        self._eaten = np.zeros(num_envs, dtype=np.int64)
        self._foods = np.zeros((num_envs, H), dtype=np.int64)
        self._onehot = np.zeros((N, num_envs))
        self._cols = np.arange(num_envs)
        self._t = H
        self._needs_reset = True

    @property
    def state(self) -> np.ndarray:
        return self._s.T.copy()

    @property
    def offered(self) -> np.ndarray:
        if self._t >= self._H:
            return np.full(self.num_envs, -1)
        return self._foods[:, self._t].copy()

    def pending_by_horizon(self) -> np.ndarray:
        t = self._t
        return self._pending[3 * t :].reshape(-1, 3, self.num_envs).sum(axis=0).T

    # ---- gymnasium API ----
    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        super().reset(seed=seed)
        foods = options.get("foods") if options else None
        self._start_day(foods)
        return self._observe(), {
            "state": self._s.T.copy(),
            "distance": self._d.copy(),
            "overshoot": np.zeros((self.num_envs, 3), dtype=bool),
            "foods_consumed": self._eaten.copy(),
            "step": np.zeros(self.num_envs, dtype=np.int64),
        }

    def _start_day(self, foods: Any = None) -> None:
        H = self._H
        if foods is not None:
            arr = np.asarray(foods)
            if arr.ndim == 1:
                arr = np.broadcast_to(arr, (self.num_envs, H))
            self._foods = self.dyn.check_foods(arr, (self.num_envs, H))
        else:
            self._foods = self.np_random.integers(0, self._N, size=(self.num_envs, H))
        self._pending[:] = 0.0
        self._s[:] = 0.0
        self._d[:] = 3.0
        self._eaten[:] = 0
        self._t = 0
        self._needs_reset = False

    def _observe(self) -> np.ndarray:
        t = self._t
        rows = self._foods[:, t] if t < self._H else np.full(self.num_envs, self._N)
        obs = self.dyn.obs_template[rows]
        obs[:, :3] = self._s.T
        if self.dyn.has_extras:
            self.dyn.write_extras(obs, t, self._pending.reshape(self._H, 3, self.num_envs))
        return obs

    def step(self, actions):
        n = self.num_envs
        if self._needs_reset:
            if self.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP and self._t == self._H:
                self._start_day()
                return self._observe(), np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool), {}
            raise RuntimeError("step() called before reset()")
        actions = np.asarray(actions).reshape(n)
        ate = actions == 1
        if not np.all(ate | (actions == 0)):
            raise ValueError(f"actions must be 0 (skip) or 1 (eat), got {np.unique(actions)}")
        t, H = self._t, self._H
        food = self._foods[:, t]
        if ate.any():
            onehot = self._onehot
            onehot[:] = 0.0
            onehot[food, self._cols] = ate
            rows = 3 * (H - t)
            due = np.matmul(self._A2T[:rows], onehot, out=self._tmp[:rows])
            self._pending[3 * t :] += due
            self._eaten += ate
        s = self._s
        s += self._pending[3 * t : 3 * t + 3]
        dev = s - 1.0
        d = np.abs(dev).sum(axis=0)
        over = np.maximum(dev, 0.0)
        progress = self._lp * (self._d - d)
        comfort = -self._lc * np.tanh(d / self._tau_c)
        overshoot = -self._lo * np.tanh((over * over).sum(axis=0))
        self._d = d
        self._t = t + 1
        truncated = np.full(n, self._t == H)
        # every value a fresh array: a later reset (SAME_STEP: this very step) rewrites the
        # env's own arrays in place, and must not change an info the caller holds
        info = {
            "state": s.T.copy(),
            "distance": d.copy(),
            "overshoot": (dev > 0.0).T,
            "foods_consumed": self._eaten.copy(),
            "ate": ate.copy(),
            "food": food.copy(),
            "step": np.full(n, self._t),
            "reward_progress": progress,
            "reward_comfort": comfort,
            "reward_overshoot": overshoot,
        }
        obs = self._observe()
        if self._t == H:
            self._needs_reset = True
            if self.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP:
                info = {**info, "final_obs": obs, "final_info": dict(info)}
                self._start_day()
                obs = self._observe()
        return obs, progress + comfort + overshoot, np.zeros(n, dtype=bool), truncated, info


def make_vector_env(num_envs: int = 1, max_episode_steps: int | None = None, **kwargs):
    """The vector entry point: a :class:`~nutribench.env.vector_env.NutriRLVectorEnv`, whose
    days end at the regime's horizon. ``gymnasium.make_vec`` passes the spec's
    ``max_episode_steps``; one below the horizon cannot be honoured and is a ValueError."""
    env = NutriRLVectorEnv(num_envs=num_envs, **kwargs)
    if max_episode_steps is not None and max_episode_steps < env.horizon:
        raise ValueError(
            f"max_episode_steps={max_episode_steps} is below the horizon {env.horizon}: the vector env runs whole "
            "days; use gymnasium.make (its TimeLimit) for shorter episodes"
        )
    return env
