"""MC (Monte Carlo actor-critic) for K agents at once: SB3's ``A2C`` update as
:class:`~nutribench.agents.builtin.mc.MonteCarloAC` makes it, every agent's parameters stacked
along a leading agent axis.

Per agent, everything is what ``algos.build_model`` builds from ``mc.toml``: the shared MLP
actor-critic (:mod:`nutribench.engine.actor_critic`), Adam with eps 1e-5, ``VecNormalize``
(each agent its own statistics); a rollout of one day (GAE lambda 1: full-episode returns),
then one gradient step on all of it: ``-(advantage * log pi)`` + value MSE + entropy bonus,
the gradient clipped per agent (no clipping when ``max_grad_norm`` is ``inf``). One update
of agent k equals SB3's update of that agent alone (``tests/test_engine.py``).
"""

from __future__ import annotations

import torch as th

from nutribench.engine.actor_critic import BatchedActorCriticAlgorithm, StackedActorCritic
from nutribench.engine.on_policy import OnPolicySettings, Rollout, gradient_step, normalized
from nutribench.engine.stacked import AgentMeans


def a2c_update(
    net: StackedActorCritic,
    optimizer: th.optim.Optimizer,
    rollout: Rollout,
    settings: OnPolicySettings,
    means: AgentMeans | None = None,
) -> None:
    """SB3 ``A2C.train()`` for the K agents: one gradient step on the whole rollout; its
    losses and gradient norms into ``means``."""
    log_prob, entropy, values = net.evaluate_actions(rollout.obs, rollout.actions)
    adv = normalized(rollout.advantages) if settings.normalize_advantage else rollout.advantages
    policy_loss = -(adv * log_prob).mean(dim=1)
    value_loss = (rollout.returns - values).pow(2).mean(dim=1)
    gradient_step(net.params, optimizer, settings, policy_loss, value_loss, -entropy.mean(dim=1), means=means)


class BatchedMC(BatchedActorCriticAlgorithm):
    """K MC agents: the shared MLP actor-critic, one A2C step per day."""

    def train(self, rollout: Rollout) -> None:
        a2c_update(self.net, self.optimizer, rollout, self.settings, self.means)
        self.log_update(rollout)
