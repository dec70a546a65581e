"""What the tests read off a trained policy besides its actions: its action probabilities
(and GRU-PPO's entropies) after one more step, GRU-PPO's state carried as ``predict`` carries it."""

from __future__ import annotations

import numpy as np
import torch as th

from nutribench.agents.gru_ppo import GRUPPO
from nutribench.agents.sac import DiscreteSAC


def gru_action_probabilities(
    model: GRUPPO,
    observation: np.ndarray,
    state: tuple[np.ndarray, ...] | None = None,
    episode_start: np.ndarray | None = None,
) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """``pi(.|history)`` after one more step, and the new state (same conventions as ``predict``)."""
    obs, vectorized, state_t, starts = model.policy.carried(observation, state, episode_start)
    with th.no_grad():
        dist, new_state = model.policy.get_distribution(obs, state_t, starts)
        probs = dist.distribution.probs.cpu().numpy()
    return (probs if vectorized else probs[0]), tuple(h.cpu().numpy() for h in new_state)


def gru_action_entropy(
    model: GRUPPO,
    observation: np.ndarray,
    state: tuple[np.ndarray, ...] | None = None,
    episode_start: np.ndarray | None = None,
) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
    """Entropy (nats) of ``pi(.|history)`` after one more step, and the new state."""
    probs, new_state = gru_action_probabilities(model, observation, state, episode_start)
    logs = np.log(np.clip(probs, 1e-30, None))
    return -(probs * logs).sum(axis=-1), new_state


def sac_action_probabilities(model: DiscreteSAC, observation: np.ndarray) -> np.ndarray:
    """``pi(.|s)`` for a batch ``(n, obs_dim)`` (or one ``(obs_dim,)``) of observations, as
    the policy sees them (already normalised when the env is wrapped in ``VecNormalize``)."""
    obs, vectorized = model.policy.obs_to_tensor(observation)
    with th.no_grad():
        probs = model.policy.action_log_probs(obs)[0].cpu().numpy()
    return probs if vectorized else probs[0]
