"""The stacked MLP actor-critic that MC and PPO train: K copies of SB3's ``ActorCriticPolicy``
with nutribench's shared backbone (``algos.build_model``), its acting, and
:class:`BatchedActorCriticAlgorithm`, the on-policy algorithm whose agents it is.

Per agent: ``obs -> 256 -> 128`` (ReLU) shared by a linear actor head (2 logits) and a
linear value head; orthogonal initialisation with SB3's gains (sqrt(2) backbone, 0.01 actor,
1 value), zero biases.
"""

from __future__ import annotations

import math

import torch as th

from nutribench.engine.evaluate import Greedy, greedy_categorical
from nutribench.engine.on_policy import BatchedOnPolicyAlgorithm, log_prob_entropy
from nutribench.engine.stacked import StackedMLP, linear_pairs, linears, orthogonal, with_zero_biases

GAINS = (math.sqrt(2), math.sqrt(2), 0.01, 1.0)  # backbone layers, actor head, value head


class StackedActorCritic(StackedMLP):
    """K copies of the shared actor-critic: parameters of shape ``(K, ...)``.

    Layers are ``(W, b)`` with ``W: (K, in, out)``, ``b: (K, 1, out)``: the backbone's layers,
    then one head layer holding the actor's logits and the value side by side (columns
    ``:n_actions`` and ``n_actions``), so that both heads are one batched product: the
    :class:`~nutribench.engine.stacked.StackedMLP` of those layers, its output split.
    """

    def __init__(
        self,
        k: int,
        obs_dim: int,
        net_arch: list[int],
        n_actions: int = 2,
        generators: list[th.Generator] | None = None,
        device: th.device | str | None = None,
    ):
        """Initialised on the CPU from ``generators`` (one per agent), then moved to ``device``."""
        sizes = [obs_dim, *net_arch]
        self.k, self.n_actions = k, n_actions
        weights = [orthogonal(k, n_in, n_out, GAINS[0], generators) for n_in, n_out in zip(sizes[:-1], sizes[1:])]
        heads = ((n_actions, GAINS[2]), (1, GAINS[3]))  # the actor's logits, then the value
        weights.append(th.cat([orthogonal(k, sizes[-1], n_out, gain, generators) for n_out, gain in heads], dim=2))
        self.params = with_zero_biases(weights, device)

    def forward(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``obs (K, B, obs_dim)`` -> logits ``(K, B, n_actions)``, values ``(K, B)``."""
        out = super().forward(obs)
        return out[..., : self.n_actions], out[..., self.n_actions]

    def evaluate_actions(self, obs: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        """``log pi(a|s)``, the policy's entropy and the values at ``obs (K, ..., d)`` and ``actions
        (K, ...)``, each flattened to ``(K, B)``."""
        logits, values = self.forward(obs.reshape(self.k, -1, obs.shape[-1]))
        return *log_prob_entropy(logits, actions.reshape(self.k, -1)), values

    def step(self, obs: th.Tensor, state: None, starts: th.Tensor) -> tuple[th.Tensor, th.Tensor, None]:
        """One acting step: ``obs (K, d)`` -> logits ``(K, n_actions)``, values ``(K,)`` and no state
        (``starts`` is for recurrent nets: a feedforward one keeps no state)."""
        logits, values = self.forward(obs.unsqueeze(1))
        return logits[:, 0], values[:, 0], state

    def sb3_pairs(self, j: int, policy) -> list[tuple[th.Tensor, th.Tensor]]:
        """Agent ``j``'s parameters and an SB3 ``ActorCriticPolicy``'s (nutribench's backbone)."""
        a, p = self.n_actions, self.params
        return [
            *linear_pairs(p, j, linears(policy.features_extractor.net)),
            (p[-2][j][:, :a], policy.action_net.weight.T),
            (p[-2][j][:, a:], policy.value_net.weight.T),
            (p[-1][j, 0, :a], policy.action_net.bias),
            (p[-1][j, 0, a:], policy.value_net.bias),
        ]


class BatchedActorCriticAlgorithm(BatchedOnPolicyAlgorithm):
    """An on-policy algorithm whose agents are the stacked MLP actor-critic (MC and PPO)."""

    @classmethod
    def forward_flops(cls, cfg, obs_dim: int, n_actions: int) -> float:
        """The ``net_arch`` backbone, the policy and value heads."""
        sizes = [obs_dim, *cfg.net_arch]
        return 2 * sum(a * b for a, b in zip(sizes[:-1], sizes[1:])) + 2 * sizes[-1] * (n_actions + 1)

    def make_network(self, generators: list[th.Generator]) -> StackedActorCritic:
        return StackedActorCritic(
            self.k, self.envs.obs_dim, list(self.cfg.net_arch), generators=generators, device=self.device
        )

    def greedy(self) -> Greedy:
        return lambda obs: greedy_categorical(self.net.forward(obs)[0])
