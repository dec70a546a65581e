"""GRU-PPO's recurrent actor-critic policy (Table 6): two GRUs, carried state, SB3 ``BasePolicy``."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.distributions import CategoricalDistribution
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn

from nutribench.agents.sb3_models import FlatDiscretePolicy

GRUState = tuple[th.Tensor, th.Tensor]
"""``(h_nutrient, h_food)``, each ``(1, batch, hidden_size)`` (nn.GRU's layout)."""


def _orthogonal_gru_init_(gru: nn.GRU, gain: float = 1.0) -> None:
    """Orthogonal init of each gate block (reset, update, new) of a GRU's weights; zero biases."""
    hidden = gru.hidden_size
    for name, param in gru.named_parameters():
        if name.startswith("weight"):
            for k in range(3):
                nn.init.orthogonal_(param.data[k * hidden : (k + 1) * hidden], gain=gain)
        else:
            nn.init.zeros_(param)


class GRUActorCriticPolicy(FlatDiscretePolicy):
    """Two-stream GRU actor-critic (the paper's Table 6); see the module docstring.

    :param observation_space: flat ``Box`` of ``n_nutrients + N`` dims (nutrients first).
    :param action_space: ``Discrete`` action space.
    :param lr_schedule: learning-rate schedule (its value at progress 1 builds the optimiser).
    :param hidden_size: hidden units of each GRU.
    :param head_size: hidden units of the actor and critic heads.
    :param n_nutrients: how many leading observation dims form the nutrient stream.
    :param ortho_init: orthogonal initialisation with zero biases.
    :param memory: carry the state from step to step (the paper's GRU-PPO); False: zero it
        before every step, in acting, training and evaluation alike (no memory: each step's
        output depends on that step's observation alone).
    :param use_sde: must be False (accepted because SB3's on-policy set-up passes it).
    :param optimizer_class: optimiser class (Adam).
    :param optimizer_kwargs: optimiser keyword arguments; default ``eps=1e-5`` for Adam, as SB3's PPO.
    """

    KEPT = ("hidden_size", "head_size", "n_nutrients", "ortho_init", "memory", "optimizer_class", "optimizer_kwargs")

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        hidden_size: int = 128,
        head_size: int = 128,
        n_nutrients: int = 3,
        ortho_init: bool = True,
        memory: bool = True,
        use_sde: bool = False,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
    ):
        if optimizer_kwargs is None:
            optimizer_kwargs = {"eps": 1e-5} if optimizer_class == th.optim.Adam else {}
        super().__init__(
            observation_space, action_space, optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs
        )
        if use_sde:
            raise ValueError("GRUActorCriticPolicy does not support gSDE")
        obs_dim, n_actions = self.sizes()
        if not 0 < n_nutrients < obs_dim:
            raise ValueError(f"n_nutrients must be in 1..{obs_dim - 1}, got {n_nutrients}")
        self.hidden_size = int(hidden_size)
        self.head_size = int(head_size)
        self.n_nutrients = int(n_nutrients)
        self.n_foods = obs_dim - self.n_nutrients
        self.ortho_init = ortho_init
        self.memory = bool(memory)

        self.nutrient_gru = nn.GRU(self.n_nutrients, self.hidden_size, num_layers=1, batch_first=True)
        self.food_gru = nn.GRU(self.n_foods, self.hidden_size, num_layers=1, batch_first=True)
        head = lambda n_out: nn.Sequential(  # noqa: E731
            nn.Linear(2 * self.hidden_size, self.head_size), nn.ReLU(), nn.Linear(self.head_size, n_out)
        )
        self.actor_head, self.critic_head = head(n_actions), head(1)
        self.action_dist = CategoricalDistribution(n_actions)

        if ortho_init:
            _orthogonal_gru_init_(self.nutrient_gru)
            _orthogonal_gru_init_(self.food_gru)
            for module, output_gain in ((self.actor_head, 0.01), (self.critic_head, 1.0)):
                # orthogonal weights, zero biases: sqrt(2) for the hidden layer, then the output's gain
                self.init_weights(module[0], gain=math.sqrt(2))
                self.init_weights(module[2], gain=output_gain)

        self.optimizer = self.optimizer_class(self.parameters(), lr=lr_schedule(1), **self.optimizer_kwargs)

    # ---- recurrent core ----

    def initial_state(self, n_envs: int) -> GRUState:
        """Zero hidden state for ``n_envs`` envs."""
        zeros = th.zeros(1, n_envs, self.hidden_size, device=self.device)
        return zeros, zeros.clone()

    def unroll(self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor) -> tuple[th.Tensor, GRUState]:
        """Run both GRUs over sequences, resetting the state where an episode starts.

        :param obs: ``(batch, T, obs_dim)`` observations (as the policy sees them).
        :param state: hidden state carried into the first step, each ``(1, batch, hidden)``.
        :param episode_starts: ``(batch, T)``, 1 where the step is the first of an episode
            (the carried state is zeroed before that step; before every step without ``memory``).
        :return: features ``(batch, T, 2 * hidden)`` (both GRUs' hidden states after each step)
            and the state after the last step.
        """
        if not self.memory:  # every step starts from the zero state
            episode_starts = th.ones_like(episode_starts)
        obs = preprocess_obs(obs, self.observation_space).float()  # type: ignore[assignment]
        batch, steps = obs.shape[0], obs.shape[1]
        nutrients, foods = obs[..., : self.n_nutrients], obs[..., self.n_nutrients :]
        keep = 1.0 - episode_starts.float().reshape(batch, steps)
        h_nut, h_food = state
        # the state reset at most before the first step: one GRU call over all steps; else
        # (an episode starts inside a sequence) step by step, zeroing the state there
        whole = steps == 1 or bool((keep[:, 1:] == 1.0).all())
        outs_nut, outs_food = [], []
        for t in [0] if whole else range(steps):
            mask, end = keep[:, t].reshape(1, batch, 1), steps if whole else t + 1
            o_nut, h_nut = self.nutrient_gru(nutrients[:, t:end], h_nut * mask)
            o_food, h_food = self.food_gru(foods[:, t:end], h_food * mask)
            outs_nut.append(o_nut)
            outs_food.append(o_food)
        return th.cat([th.cat(outs_nut, dim=1), th.cat(outs_food, dim=1)], dim=-1), (h_nut, h_food)

    def _step(self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor) -> tuple[th.Tensor, GRUState]:
        """One step for a batch of envs: ``obs (n, obs_dim)``, ``episode_starts (n,)`` -> features ``(n, 2H)``."""
        features, new_state = self.unroll(obs.unsqueeze(1), state, episode_starts.reshape(-1, 1))
        return features[:, 0], new_state

    # ---- acting ----

    def forward(
        self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor, deterministic: bool = False
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor, GRUState]:
        """One acting step: ``(actions, values, log_probs, new_state)``."""
        features, new_state = self._step(obs, state, episode_starts)
        dist = self.action_dist.proba_distribution(self.actor_head(features))
        actions = dist.get_actions(deterministic=deterministic)
        return actions, self.critic_head(features), dist.log_prob(actions), new_state

    def get_distribution(
        self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor
    ) -> tuple[CategoricalDistribution, GRUState]:
        """Action distribution after one step from ``state`` (and the new state)."""
        features, new_state = self._step(obs, state, episode_starts)
        return self.action_dist.proba_distribution(self.actor_head(features)), new_state

    def predict_values(self, obs: th.Tensor, state: GRUState, episode_starts: th.Tensor) -> th.Tensor:
        """``(n, 1)`` values after one step from ``state``."""
        features, _ = self._step(obs, state, episode_starts)
        return self.critic_head(features)

    # ---- training ----

    def evaluate_actions(
        self, obs: th.Tensor, actions: th.Tensor, state: GRUState, episode_starts: th.Tensor
    ) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """Values, log-probabilities of ``actions`` and entropies over whole sequences.

        :param obs: ``(batch, T, obs_dim)``; :param actions: ``(batch, T)``;
        :param state: state carried into the first step; :param episode_starts: ``(batch, T)``.
        :return: three ``(batch * T,)`` tensors, in (sequence, step) order. Each step's outputs
            depend on every earlier step of its episode through the recurrent state.
        """
        features, _ = self.unroll(obs, state, episode_starts)
        features = features.reshape(-1, features.shape[-1])
        dist = self.action_dist.proba_distribution(self.actor_head(features))
        return self.critic_head(features).flatten(), dist.log_prob(actions.reshape(-1).long()), dist.entropy()

    # ---- SB3 predict API (sb3-contrib RecurrentPPO semantics) ----

    def carried(
        self, observation: np.ndarray, state: tuple[np.ndarray, ...] | None, episode_start: np.ndarray | None
    ) -> tuple[th.Tensor, bool, GRUState, th.Tensor]:
        """:meth:`predict`'s arguments as tensors on the policy's device, the policy put in
        evaluation mode: the observations and whether they were a batch, the state (zeros
        where None) and the episode starts (none where None)."""
        self.set_training_mode(False)
        obs, vectorized = self.obs_to_tensor(observation)
        n = obs.shape[0]  # type: ignore[union-attr]
        state_t = (
            self.initial_state(n)
            if state is None
            else tuple(th.as_tensor(s, dtype=th.float32, device=self.device) for s in state)
        )
        starts = np.zeros(n, dtype=np.float32) if episode_start is None else np.asarray(episode_start, dtype=np.float32)
        return obs, vectorized, state_t, th.as_tensor(starts.reshape(n), device=self.device)  # type: ignore[return-value]

    def _predict(  # type: ignore[override]
        self, observation: PyTorchObs, state: GRUState, episode_starts: th.Tensor, deterministic: bool = False
    ) -> tuple[th.Tensor, GRUState]:
        """Actions and the new state after one step from ``state`` (:meth:`carried` makes the
        defaults of :meth:`predict`'s arguments)."""
        actions, _, _, new_state = self.forward(observation, state, episode_starts, deterministic)  # type: ignore[arg-type]
        return actions, new_state

    def predict(  # type: ignore[override]
        self,
        observation: np.ndarray,
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...]]:
        """Action(s) and the next hidden state, carried like sb3-contrib's ``RecurrentPPO``.

        :param observation: ``(n_envs, obs_dim)`` or one ``(obs_dim,)`` observation.
        :param state: the state returned by the previous call (None: zero state).
        :param episode_start: ``(n_envs,)`` bools, True where ``observation`` is the first of an
            episode (the state is reset there); None means False everywhere.
        :param deterministic: argmax action instead of a sample.
        :return: ``(actions, (h_nutrient, h_food))``, states as ``(1, n_envs, hidden)`` arrays.
        """
        obs_tensor, vectorized, state_t, starts = self.carried(observation, state, episode_start)
        with th.no_grad():
            actions, new_state = self._predict(obs_tensor, state_t, starts, deterministic)  # type: ignore[arg-type]
        actions_np = actions.cpu().numpy().reshape((-1, *self.action_space.shape))  # type: ignore[misc]
        if not vectorized:
            actions_np = actions_np.squeeze(axis=0)
        return actions_np, tuple(h.cpu().numpy() for h in new_state)
