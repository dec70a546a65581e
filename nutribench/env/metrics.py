"""Per-episode metrics (the paper's evaluation metrics), recorded from the envs' infos (batched).

``return``, ``foods`` consumed, ``final_distance`` |s_H - T|_1, ``overshoot_ratio`` (the
fraction of the episode's steps at which any nutrient is above target), the final state
``final_C`` / ``final_F`` / ``final_P`` and ``first_overshoot_step`` (1-based, ``None`` if
the episode never overshot).
"""

from __future__ import annotations

from typing import Any

import numpy as np

METRIC_KEYS = (
    "return",
    "foods",
    "final_distance",
    "overshoot_ratio",
    "final_C",
    "final_F",
    "final_P",
    "first_overshoot_step",
)


class EpisodeRecorder:
    """Accumulates the metrics of ``num_envs`` parallel episodes from per-step infos."""

    def __init__(self, num_envs: int):
        self.num_envs = num_envs
        self._ret = np.zeros(num_envs)
        self._over_steps = np.zeros(num_envs, dtype=np.int64)
        self._steps = np.zeros(num_envs, dtype=np.int64)
        self._first_over = np.full(num_envs, -1, dtype=np.int64)

    def clear(self, mask: np.ndarray | None = None) -> None:
        """Start the episodes of the envs ``mask`` (default: all) afresh."""
        where = slice(None) if mask is None else mask
        self._ret[where] = 0.0
        self._over_steps[where] = 0
        self._steps[where] = 0
        self._first_over[where] = -1

    def record(self, rewards: np.ndarray, done: np.ndarray, info: dict[str, Any]) -> list[dict[str, Any]]:
        """Add one step (batched); return the metrics of the episodes that ended at it."""
        self._ret += rewards
        self._steps += 1
        over_any = np.asarray(info["overshoot"]).reshape(self.num_envs, 3).any(axis=1)
        self._over_steps += over_any
        first = over_any & (self._first_over < 0)
        self._first_over[first] = self._steps[first]
        done = np.asarray(done, dtype=bool).reshape(self.num_envs)
        if not done.any():
            return []
        state = np.asarray(info["state"]).reshape(self.num_envs, 3)
        foods = np.asarray(info["foods_consumed"]).reshape(self.num_envs)
        dist = np.asarray(info["distance"]).reshape(self.num_envs)
        out = []
        for j in np.flatnonzero(done):
            fo = int(self._first_over[j])
            values = (float(self._ret[j]), int(foods[j]), float(dist[j]), float(self._over_steps[j] / self._steps[j]))
            values += (float(state[j, 0]), float(state[j, 1]), float(state[j, 2]), fo if fo > 0 else None)
            out.append(dict(zip(METRIC_KEYS, values)))  # in METRIC_KEYS' order
        self.clear(done)
        return out


def play(
    env, policy, episodes: int = 1, seed: int | None = None, foods: np.ndarray | None = None
) -> list[dict[str, Any]]:
    """Play ``policy`` for ``episodes`` days on a vector env (one day per env) or a single env.

    With a vector env, ``episodes`` must equal ``env.num_envs``; ``foods`` (episodes x H)
    fixes the food streams.
    """
    if hasattr(env, "num_envs"):  # a vector env
        if episodes != env.num_envs:
            raise ValueError(f"a vector env plays num_envs={env.num_envs} episodes at once, asked for {episodes}")
        options = {"foods": foods} if foods is not None else None
        _, info = env.reset(seed=seed, options=options)
        rec = EpisodeRecorder(env.num_envs)
        results: list[dict[str, Any]] = []
        while not results:
            _, r, term, trunc, info = env.step(policy(env))
            results = rec.record(r, term | trunc, info)
        return results
    results = []
    rec = EpisodeRecorder(1)
    for ep in range(episodes):
        options = {"foods": foods[ep]} if foods is not None else None
        env.reset(seed=seed if ep == 0 else None, options=options)
        done = False
        while not done:
            _, r, term, trunc, info = env.step(policy(env))
            done = term or trunc
            results += rec.record(np.array([r]), np.array([done]), info)
    return results
