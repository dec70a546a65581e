"""PPO for K agents at once: SB3's ``PPO.train()`` with every agent's parameters stacked
along a leading agent axis; its loss and gradient step on a :class:`~nutribench.engine.on_policy.Minibatch` (:func:`ppo_step`) are GRU-PPO's too
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

import numpy as np
import torch as th

from nutribench import diagnostics as names
from nutribench.engine.actor_critic import BatchedActorCriticAlgorithm, StackedActorCritic, evaluate_actions
from nutribench.engine.on_policy import Minibatch, OnPolicySettings, Rollout, gradient_step, normalized
from nutribench.engine.stacked import AgentMeans, per_agent


def ppo_step(
    params: list[th.Tensor],
    optimizer: th.optim.Optimizer,
    settings: OnPolicySettings,
    minibatch: Minibatch,
    k: int | None = None,
    means: AgentMeans | None = None,
    last_epoch: bool = True,
) -> None:
    """PPO's loss on one minibatch of the K agents and one gradient step on it
    (:func:`~nutribench.engine.on_policy.gradient_step`); the losses, gradient norms and clip
    fraction into ``means``, and in the ``last_epoch`` the approximate KL (SB3 logs
    ``train/approx_kl`` of its last epoch's minibatches only)."""
    mb = minibatch
    use_norm = settings.normalize_advantage and mb.advantages.shape[1] > 1
    adv = normalized(mb.advantages) if use_norm else mb.advantages
    log_ratio = mb.log_prob - mb.old_log_prob
    ratio = th.exp(log_ratio)
    clip = per_agent(settings.clip_range, ratio, ndim=2)  # a (K, 1) tensor: each agent's own range
    surrogate = th.min(adv * ratio, adv * th.clamp(ratio, 1 - clip, 1 + clip))
    policy_loss = -surrogate.mean(dim=1)
    value_loss = (mb.returns - mb.values).pow(2).mean(dim=1)
    gradient_step(params, optimizer, settings, policy_loss, value_loss, -mb.entropy.mean(dim=1), k, means)
    if means is not None:
        with th.no_grad():  # as SB3 logs them
            means.add(**{names.CLIP_FRACTION: ((ratio - 1).abs() > clip).float().mean(dim=1)})
            if last_epoch:
                means.add(**{names.APPROX_KL: ((ratio - 1) - log_ratio).mean(dim=1)})


def ppo_update(
    net: StackedActorCritic,
    optimizer: th.optim.Optimizer,
    rollout: Rollout,
    settings: OnPolicySettings,
    permutations: np.ndarray,
    means: AgentMeans | None = None,
) -> None:
    """SB3 ``PPO.train()`` for the K agents: ``permutations (n_epochs, K, T)`` order each
    agent's transitions in each epoch (SB3 draws ``np.random.permutation(T)``); each
    minibatch's losses and gradient norms into ``means``."""
    k, t_max = rollout.actions.shape
    device = rollout.actions.device
    rows = th.arange(k, device=device).unsqueeze(1)
    for epoch in range(settings.n_epochs):
        perm = th.as_tensor(permutations[epoch], device=device)
        # the epoch's order once, then contiguous minibatches of it (SB3's order exactly)
        obs_e, act_e, adv_e = rollout.obs[rows, perm], rollout.actions[rows, perm], rollout.advantages[rows, perm]
        logp_e, ret_e = rollout.log_probs[rows, perm], rollout.returns[rows, perm]
        for start in range(0, t_max, settings.batch_size):
            mb = slice(start, start + settings.batch_size)
            log_prob, entropy, values = evaluate_actions(net, obs_e[:, mb], act_e[:, mb])
            minibatch = Minibatch(log_prob, entropy, values, logp_e[:, mb], adv_e[:, mb], ret_e[:, mb])
            last_epoch = epoch == settings.n_epochs - 1
            ppo_step(net.params, optimizer, settings, minibatch, means=means, last_epoch=last_epoch)


class BatchedPPO(BatchedActorCriticAlgorithm):
    """K PPO agents: the shared MLP actor-critic, SB3's PPO update."""

    def train(self, rollout: Rollout) -> None:
        ppo_update(self.net, self.optimizer, rollout, self.settings, self.permutations(rollout), self.means)
        self.log_update(rollout)
