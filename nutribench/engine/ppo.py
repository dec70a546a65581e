"""PPO for K agents at once: SB3's ``PPO.train()`` with every agent's parameters stacked
along a leading agent axis; its loss and gradient step (:func:`ppo_step`) are GRU-PPO's too
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
from nutribench.engine.actor_critic import ActorCriticAlgorithm, StackedActorCritic, evaluate_actions
from nutribench.engine.on_policy import OnPolicySettings, Rollout, gradient_step, normalized
from nutribench.engine.stacked import AgentMeans


def ppo_step(
    params: list[th.Tensor],
    optimizer: th.optim.Optimizer,
    s: OnPolicySettings,
    log_prob: th.Tensor,
    entropy: th.Tensor,
    values: th.Tensor,
    old_log_prob: th.Tensor,
    advantages: th.Tensor,
    returns: th.Tensor,
    k: int | None = None,
    means: AgentMeans | None = None,
) -> None:
    """PPO's loss on one minibatch of the K agents (each ``(K, B)``: the policy's log
    probabilities, entropy and values now, the rollout's log probabilities, advantages and
    returns) and one gradient step on it (:func:`~nutribench.engine.on_policy.gradient_step`);
    the losses, gradient norms, approximate KL and clip fraction into ``means``."""
    adv = normalized(advantages) if s.normalize_advantage and advantages.shape[1] > 1 else advantages
    log_ratio = log_prob - old_log_prob
    ratio = th.exp(log_ratio)
    surrogate = th.min(adv * ratio, adv * th.clamp(ratio, 1 - s.clip_range, 1 + s.clip_range))
    policy_loss = -surrogate.mean(dim=1)
    value_loss = (returns - values).pow(2).mean(dim=1)
    gradient_step(params, optimizer, s, policy_loss, value_loss, -entropy.mean(dim=1), k, means)
    if means is not None:
        with th.no_grad():  # as SB3 logs them
            means.add(
                **{
                    names.APPROX_KL: ((ratio - 1) - log_ratio).mean(dim=1),
                    names.CLIP_FRACTION: ((ratio - 1).abs() > s.clip_range).float().mean(dim=1),
                }
            )


def ppo_update(
    net: StackedActorCritic,
    optimizer: th.optim.Optimizer,
    rollout: Rollout,
    s: OnPolicySettings,
    permutations: np.ndarray,
    means: AgentMeans | None = None,
) -> None:
    """SB3 ``PPO.train()`` for the K agents: ``permutations (n_epochs, K, T)`` order each
    agent's transitions in each epoch (SB3 draws ``np.random.permutation(T)``); each
    minibatch's losses and gradient norms into ``means``."""
    k, t_max = rollout.actions.shape
    device = rollout.actions.device
    rows = th.arange(k, device=device).unsqueeze(1)
    for epoch in range(s.n_epochs):
        perm = th.as_tensor(permutations[epoch], device=device)
        # the epoch's order once, then contiguous minibatches of it (SB3's order exactly)
        obs_e, act_e, adv_e = rollout.obs[rows, perm], rollout.actions[rows, perm], rollout.advantages[rows, perm]
        logp_e, ret_e = rollout.log_probs[rows, perm], rollout.returns[rows, perm]
        for start in range(0, t_max, s.batch_size):
            mb = slice(start, start + s.batch_size)
            log_prob, entropy, values = evaluate_actions(net, obs_e[:, mb], act_e[:, mb])
            ppo_step(
                net.params,
                optimizer,
                s,
                log_prob,
                entropy,
                values,
                logp_e[:, mb],
                adv_e[:, mb],
                ret_e[:, mb],
                means=means,
            )


class PPO(ActorCriticAlgorithm):
    """K PPO agents: the shared MLP actor-critic, SB3's PPO update."""

    algo = "ppo"

    def update(self, rollout: Rollout, permutations: np.ndarray) -> None:
        ppo_update(self.net, self.optimizer, rollout, self.settings, permutations, self.means)
