"""GRU-PPO's rollout buffer: each env's time line cut into whole sequences with their starting GRU state."""

from __future__ import annotations

from collections.abc import Generator
from typing import NamedTuple

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import RolloutBuffer

from nutribench.agents.gru_ppo.policy import GRUState


class RecurrentRolloutBufferSamples(NamedTuple):
    """A minibatch of whole sequences (B sequences of T steps)."""

    observations: th.Tensor  # (B, T, obs_dim)
    actions: th.Tensor  # (B, T)
    old_values: th.Tensor  # (B * T,)
    old_log_prob: th.Tensor  # (B * T,)
    advantages: th.Tensor  # (B * T,)
    returns: th.Tensor  # (B * T,)
    episode_starts: th.Tensor  # (B, T)
    hidden_states: GRUState  # state carried into each sequence's first step, each (1, B, H)


class RecurrentRolloutBuffer(RolloutBuffer):
    """SB3's ``RolloutBuffer`` plus, per step, the GRU state carried into that step; serves
    minibatches of whole sequences of ``sequence_length`` consecutive steps of one env.

    GAE and returns are SB3's (``compute_returns_and_advantage`` is inherited, and already
    uses ``episode_starts``). ``get(n_sequences)`` yields :class:`RecurrentRolloutBufferSamples`.

    :param buffer_size: steps per env (``n_steps``), a multiple of ``sequence_length``.
    :param hidden_size: GRU hidden size.
    :param sequence_length: steps per training sequence (NutriRL's episode length, 50).
    """

    hidden_states: np.ndarray
    #: the per-step arrays served cut into sequences
    SEQUENCED = ("observations", "actions", "values", "log_probs", "advantages", "returns", "episode_starts")

    def __init__(
        self,
        buffer_size: int,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        device: th.device | str = "auto",
        gae_lambda: float = 1,
        gamma: float = 0.99,
        n_envs: int = 1,
        hidden_size: int = 128,
        sequence_length: int = 50,
    ):
        if sequence_length < 1 or buffer_size % sequence_length != 0:
            raise ValueError(
                f"the rollout length n_steps={buffer_size} must be a multiple of sequence_length={sequence_length} "
                "(the episode length: training replays whole episodes through the GRU)"
            )
        self.hidden_size = hidden_size
        self.sequence_length = sequence_length
        super().__init__(buffer_size, observation_space, action_space, device, gae_lambda, gamma, n_envs)

    @property
    def n_sequences(self) -> int:
        return (self.buffer_size // self.sequence_length) * self.n_envs

    def reset(self) -> None:
        super().reset()
        # (step, env, stream, hidden); stream 0 = nutrient GRU, 1 = food GRU
        self.hidden_states = np.zeros((self.buffer_size, self.n_envs, 2, self.hidden_size), dtype=np.float32)

    def add(self, *args, hidden_state: GRUState, **kwargs) -> None:  # type: ignore[override]
        """SB3's ``add(obs, action, reward, episode_start, value, log_prob)`` plus the state
        carried into this step (before the ``episode_start`` reset)."""
        for stream, h in enumerate(hidden_state):  # 0: the nutrient GRU's, 1: the food GRU's
            self.hidden_states[self.pos, :, stream] = h[0].cpu().numpy()
        super().add(*args, **kwargs)

    def to_sequences(self, arr: np.ndarray) -> np.ndarray:
        """``(n_steps, n_envs, *rest)`` -> ``(n_sequences, T, *rest)``: each env's time line cut
        into consecutive chunks of T steps (sequence index = chunk * n_envs + env)."""
        T = self.sequence_length
        rest = arr.shape[2:]
        chunks = arr.reshape(self.buffer_size // T, T, self.n_envs, *rest)
        return chunks.swapaxes(1, 2).reshape(self.n_sequences, T, *rest)

    def get(self, batch_size: int | None = None) -> Generator[RecurrentRolloutBufferSamples, None, None]:  # type: ignore[override]
        """Shuffled minibatches of ``batch_size`` whole sequences (None: all in one)."""
        assert self.full, "the rollout buffer is not full"
        if not self.generator_ready:  # reshape once per rollout (reset() clears the flag)
            self._sequences = {name: self.to_sequences(getattr(self, name)) for name in self.SEQUENCED}
            # state carried into each sequence's first step: (n_seq, 2, H)
            self._sequences["hidden_states"] = self.to_sequences(self.hidden_states)[:, 0]
            self.generator_ready = True
        seq = self._sequences
        n_seq = self.n_sequences
        if batch_size is None:
            batch_size = n_seq
        indices = np.random.permutation(n_seq)
        for start in range(0, n_seq, batch_size):
            yield self._get_sequence_samples(seq, indices[start : start + batch_size])

    def _get_sequence_samples(self, seq: dict[str, np.ndarray], idx: np.ndarray) -> RecurrentRolloutBufferSamples:
        hidden = self.to_torch(seq["hidden_states"][idx])  # (B, 2, H)
        return RecurrentRolloutBufferSamples(
            observations=self.to_torch(seq["observations"][idx]),
            actions=self.to_torch(seq["actions"][idx].reshape(len(idx), self.sequence_length)),
            old_values=self.to_torch(seq["values"][idx].reshape(-1)),
            old_log_prob=self.to_torch(seq["log_probs"][idx].reshape(-1)),
            advantages=self.to_torch(seq["advantages"][idx].reshape(-1)),
            returns=self.to_torch(seq["returns"][idx].reshape(-1)),
            episode_starts=self.to_torch(seq["episode_starts"][idx]),
            hidden_states=(hidden[:, 0].unsqueeze(0).contiguous(), hidden[:, 1].unsqueeze(0).contiguous()),
        )
