"""Discrete SAC's networks and policy: the categorical actor, twin Q-networks and their targets."""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import torch as th
from gymnasium import spaces
from stable_baselines3.common.preprocessing import preprocess_obs
from stable_baselines3.common.torch_layers import create_mlp
from stable_baselines3.common.type_aliases import PyTorchObs, Schedule
from torch import nn
from torch.nn import functional as F

from nutribench.agents.sb3_models import FlatDiscretePolicy


class TwinQNetwork(nn.Module):
    """Two independent Q-networks, each mapping an observation to one Q-value per action."""

    def __init__(self, obs_dim: int, n_actions: int, net_arch: Sequence[int], activation_fn: type[nn.Module] = nn.ReLU):
        super().__init__()
        self.q1 = nn.Sequential(*create_mlp(obs_dim, n_actions, list(net_arch), activation_fn))
        self.q2 = nn.Sequential(*create_mlp(obs_dim, n_actions, list(net_arch), activation_fn))

    def forward(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        return self.q1(obs), self.q2(obs)


class DiscreteSACPolicy(FlatDiscretePolicy):
    """Categorical actor + twin Q critics + their two target copies, with one Adam optimiser each
    for the actor (``actor_optimizer``) and for both critics (``critic_optimizer``).

    ``predict(obs, deterministic=True)`` returns ``argmax_a pi(a|s)``; ``deterministic=False``
    samples from ``pi``.

    :param observation_space: flat ``Box`` observation space.
    :param action_space: ``Discrete`` action space.
    :param lr_schedule: learning-rate schedule used to build both optimisers; the algorithm
        then sets each optimiser's own rate (actor and critic rates differ).
    :param net_arch: hidden layer sizes of the actor and of each critic.
    :param activation_fn: activation between hidden layers.
    :param optimizer_class: optimiser class (Adam).
    :param optimizer_kwargs: extra optimiser keyword arguments (besides the learning rate).
    """

    KEPT = ("net_arch", "activation_fn", "optimizer_class", "optimizer_kwargs")

    def __init__(
        self,
        observation_space: spaces.Space,
        action_space: spaces.Space,
        lr_schedule: Schedule,
        net_arch: Sequence[int] = (256, 128),
        activation_fn: type[nn.Module] = nn.ReLU,
        optimizer_class: type[th.optim.Optimizer] = th.optim.Adam,
        optimizer_kwargs: dict[str, Any] | None = None,
    ):
        super().__init__(
            observation_space, action_space, optimizer_class=optimizer_class, optimizer_kwargs=optimizer_kwargs
        )
        obs_dim, n_actions = self.sizes()
        self.net_arch = [int(n) for n in net_arch]
        self.activation_fn = activation_fn

        self.actor = nn.Sequential(*create_mlp(obs_dim, n_actions, self.net_arch, activation_fn))
        self.critic = TwinQNetwork(obs_dim, n_actions, self.net_arch, activation_fn)
        self.critic_target = copy.deepcopy(self.critic)
        self.critic_target.requires_grad_(False)
        self.critic_target.train(False)

        rate = lr_schedule(1)
        self.actor_optimizer = self.optimizer_class(self.actor.parameters(), lr=rate, **self.optimizer_kwargs)
        self.critic_optimizer = self.optimizer_class(self.critic.parameters(), lr=rate, **self.optimizer_kwargs)

    def set_training_mode(self, mode: bool) -> None:
        self.actor.train(mode)
        self.critic.train(mode)
        self.training = mode  # the target critic always stays in eval mode

    def _obs(self, obs: PyTorchObs) -> th.Tensor:
        return preprocess_obs(obs, self.observation_space).float()  # type: ignore[return-value]

    def action_log_probs(self, obs: PyTorchObs) -> tuple[th.Tensor, th.Tensor]:
        """``(probs, log_probs)``, each ``(batch, n_actions)``, of the policy at ``obs``."""
        log_probs = F.log_softmax(self.actor(self._obs(obs)), dim=-1)
        return log_probs.exp(), log_probs

    def entropy(self, obs: PyTorchObs) -> th.Tensor:
        """``(batch,)`` entropy ``-sum_a pi(a|s) log pi(a|s)`` of the action distribution."""
        probs, log_probs = self.action_log_probs(obs)
        return -(probs * log_probs).sum(dim=-1)

    def q_values(self, obs: PyTorchObs, target: bool = False) -> tuple[th.Tensor, th.Tensor]:
        """``(Q1, Q2)`` at ``obs``, each ``(batch, n_actions)``; ``target=True`` uses the target nets."""
        critic = self.critic_target if target else self.critic
        return critic(self._obs(obs))

    def forward(self, obs: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        return self._predict(obs, deterministic=deterministic)

    def _predict(self, observation: PyTorchObs, deterministic: bool = False) -> th.Tensor:
        logits = self.actor(self._obs(observation))
        if deterministic:
            return logits.argmax(dim=-1)
        return th.distributions.Categorical(logits=logits, validate_args=False).sample()
