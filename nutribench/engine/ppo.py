"""PPO for K agents at once: SB3's ``PPO.train()`` with every agent's parameters stacked
along a leading agent axis; its update (:func:`ppo_update`) is GRU-PPO's too, over whole days
(:mod:`nutribench.engine.gru_ppo`).

Per agent, everything is what :class:`stable_baselines3.PPO` with nutribench's shared
backbone does (``algos.build_model`` from ``ppo.toml``): the shared MLP actor-critic
(:mod:`nutribench.engine.actor_critic`), Adam with eps 1e-5, ``VecNormalize`` (each agent
its own statistics); rollouts of ``n_steps`` env steps, GAE (gamma, lambda), a day's end a
true terminal; ``n_epochs`` passes over the rollout in minibatches of ``batch_size`` drawn by
a random permutation; advantages normalised per minibatch; clipped surrogate; unclipped
value loss; entropy bonus; the gradient clipped to ``max_grad_norm`` in L2 over the agent's
own parameters. One update of agent k equals SB3's update of that agent alone
(``tests/test_engine.py``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch as th

from nutribench import diagnostics as names
from nutribench.engine.actor_critic import BatchedActorCriticAlgorithm
from nutribench.engine.on_policy import OnPolicySettings, Rollout, gradient_step, normalized
from nutribench.engine.stacked import AgentMeans, per_agent


def ppo_update(
    net: Any,
    optimizer: th.optim.Optimizer,
    rollout: Rollout,
    settings: OnPolicySettings,
    permutations: np.ndarray,
    means: AgentMeans | None = None,
) -> None:
    """SB3 ``PPO.train()`` for the K agents (GRU-PPO: ``GRUPPO.train()``, its units whole days of
    ``settings.sequence_length`` steps, each replayed whole through the GRUs): ``permutations
    (n_epochs, K, units)`` order each agent's units (transitions, or days) in each epoch (SB3
    draws ``np.random.permutation``), minibatches of ``batch_size`` units each, ``net.evaluate_actions``
    at them; PPO's loss and one gradient step per minibatch
    (:func:`~nutribench.engine.on_policy.gradient_step`). The losses, gradient norms and clip
    fraction go to ``means``, and in the last epoch the approximate KL (SB3 logs
    ``train/approx_kl`` of its last epoch's minibatches only)."""
    k, t_all = rollout.actions.shape
    n_units = t_all // (settings.sequence_length or 1)
    device = rollout.actions.device
    rows = th.arange(k, device=device).unsqueeze(1)
    fields = (rollout.obs, rollout.actions, rollout.log_probs, rollout.advantages, rollout.returns)
    units = [x.reshape(k, n_units, -1, *x.shape[2:]) for x in fields]  # (K, units, steps of a unit, ...)
    for epoch in range(settings.n_epochs):
        perm = th.as_tensor(permutations[epoch], device=device)
        for start in range(0, n_units, settings.batch_size):
            mb = perm[:, start : start + settings.batch_size]
            obs, actions, old_log_prob, adv, returns = (x[rows, mb] for x in units)
            log_prob, entropy, values = net.evaluate_actions(obs, actions)
            old_log_prob, adv, returns = (x.reshape(k, -1) for x in (old_log_prob, adv, returns))
            if settings.normalize_advantage and adv.shape[1] > 1:
                adv = normalized(adv)
            log_ratio = log_prob - old_log_prob
            ratio = th.exp(log_ratio)
            clip = per_agent(settings.clip_range, ratio, ndim=2)  # a (K, 1) tensor: each agent's own range
            policy_loss = -th.min(adv * ratio, adv * th.clamp(ratio, 1 - clip, 1 + clip)).mean(dim=1)
            value_loss = (returns - values).pow(2).mean(dim=1)
            gradient_step(net.params, optimizer, settings, policy_loss, value_loss, -entropy.mean(dim=1), k, means)
            if means is not None:
                with th.no_grad():  # as SB3 logs them
                    means.add(**{names.CLIP_FRACTION: ((ratio - 1).abs() > clip).float().mean(dim=1)})
                    if epoch == settings.n_epochs - 1:
                        means.add(**{names.APPROX_KL: ((ratio - 1) - log_ratio).mean(dim=1)})


class BatchedPPO(BatchedActorCriticAlgorithm):
    """K PPO agents: the shared MLP actor-critic, SB3's PPO update."""

    def train(self, rollout: Rollout) -> None:
        ppo_update(self.net, self.optimizer, rollout, self.settings, self.permutations(rollout), self.means)
        self.log_update(rollout)
