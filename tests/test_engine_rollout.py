"""A PPO rollout that ends inside a day bootstraps from the value of the next
observation. With ``n_steps = 30`` and 50-step days most rollouts end mid-day; with a
learning rate of 0 the network never moves, so the value the engine bootstrapped from is
the next rollout's first value (the same observation, the same network). Each rollout's
advantages and returns must equal SB3's ``RolloutBuffer.compute_returns_and_advantage`` on
the same rewards, values and day starts with that bootstrap, and its last step's advantage
the one-step hand computation ``r + gamma V(s') - V(s)``."""

from __future__ import annotations

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer

from nutribench.agents.config import load_agent_config
from nutribench.engine.train import train_batched

N_STEPS = 30  # cuts the 50-step days
DAYS = 5  # 250 steps: 8 rollouts (the rollout ending at step 150 ends a day), then a partial one


def _sb3_gae(
    r: dict[str, np.ndarray], j: int, last_value: float, last_done: bool, gamma: float, lam: float
) -> tuple[np.ndarray, np.ndarray]:
    """Agent ``j``'s advantages and returns of rollout ``r`` by SB3's rollout buffer."""
    t_max, obs_dim = r["obs"].shape[1:]
    buf = RolloutBuffer(
        t_max, spaces.Box(-np.inf, np.inf, (obs_dim,)), spaces.Discrete(2), n_envs=1, gamma=gamma, gae_lambda=lam
    )
    for t in range(t_max):
        buf.add(
            r["obs"][j, t : t + 1],
            r["actions"][j, t : t + 1, None],
            r["rewards"][j, t : t + 1],
            r["starts"][j, t : t + 1],
            th.tensor([r["values"][j, t]]),
            th.zeros(1),
        )
    buf.compute_returns_and_advantage(th.tensor([last_value]), np.array([last_done]))
    return buf.advantages[:, 0], buf.returns[:, 0]


def test_a_rollout_that_ends_inside_a_day_bootstraps_from_the_next_observation_s_value() -> None:
    cfg = load_agent_config("ppo").model_copy(
        update=dict(n_steps=N_STEPS, batch_size=N_STEPS, n_epochs=1, learning_rate=0.0)
    )
    rollouts: list[dict[str, np.ndarray]] = []
    train_batched(
        [("run0", 0), ("run3", 1)], cfg, DAYS, on_rollout=lambda r: rollouts.append({k: v.copy() for k, v in r.items()})
    )
    assert len(rollouts) == DAYS * 50 // N_STEPS
    ends_inside_a_day = 0
    for r, after in zip(rollouts, rollouts[1:]):  # the last one's next observation is not recorded
        next_values, next_starts = after["values"][:, 0], after["starts"][:, 0].astype(bool)
        for j in range(2):
            adv, ret = _sb3_gae(r, j, float(next_values[j]), bool(next_starts[j]), cfg.gamma, cfg.gae_lambda)
            np.testing.assert_allclose(r["advantages"][j], adv, rtol=1e-5, atol=1e-5)
            np.testing.assert_allclose(r["returns"][j], ret, rtol=1e-5, atol=1e-5)
        # the last step by hand: one TD error, bootstrapped unless the day ended there
        bootstrap = cfg.gamma * next_values * (1.0 - next_starts)
        np.testing.assert_allclose(
            r["advantages"][:, -1], r["rewards"][:, -1] + bootstrap - r["values"][:, -1], rtol=1e-5, atol=1e-5
        )
        if not next_starts.any():
            ends_inside_a_day += 1
            assert np.abs(bootstrap).min() > 1e-3  # a zeroed bootstrap would show
        else:
            assert next_starts.all()  # one horizon: every agent's day ends at once
    assert ends_inside_a_day >= 5
