"""Discrete SAC for K agents at once: :class:`~nutribench.agents.sac.DiscreteSAC`'s update
with every agent's parameters stacked along a leading agent axis.

Per agent, everything is what ``algos.build_model`` builds from ``sac.toml``:

* a categorical actor ``obs -> 256 -> 128 -> 2`` and twin critics of the same shape (one Q
  per action), PyTorch's default ``Linear`` initialisation, target critics copied from
  them; one Adam (eps 1e-8) for the actor and one for both critics, each at its own rate;
* ``VecNormalize`` of the observations; SB3's off-policy loop
  (:class:`~nutribench.engine.off_policy.BatchedOffPolicyAlgorithm`) with its one-step replay: uniformly
  random actions for the first ``learning_starts`` steps, then actions drawn from the policy;
* each update: the critics regress the soft Bellman target ``r + gamma (1 - done)
  sum_a pi(a|s') (min Q_targ(s', a) - alpha log pi(a|s'))`` (MSE, both critics); then the
  actor minimises ``sum_a pi(a|s) (alpha log pi(a|s) - min Q(s, a))`` against the
  just-updated critics; then the targets move by Polyak averaging (``tau``).

The twin critics of the K agents are one stack of 2K networks (first critics, then second
critics), so that both are one batched product. The day's entropy recorded for each agent
is the policy's at the moment it acted (the SB3 engine's is the end-of-day policy's on the
day's observations; SAC's policy moves every step, so the two differ slightly).

Each training day's diagnostics: the means over its gradient steps of the critic loss (as
``value_loss``), the actor loss, the mean of the twin critics' minimum at the actions taken
(``q_mean``, before the critics' step), ``ent_coef`` (alpha, fixed) and the critics' learning
rate (SB3's ``lr_schedule`` in :class:`~nutribench.agents.sac.DiscreteSAC`). No gradient norm:
the engine does not clip SAC's gradients (nor does SAC).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
import torch as th

from nutribench import diagnostics as names
from nutribench.engine.envs import AgentEnvs
from nutribench.engine.evaluate import Greedy, greedy_categorical
from nutribench.engine.off_policy import OFF_POLICY_ADAM_EPS, Batch, BatchedOffPolicyAlgorithm
from nutribench.engine.stacked import AgentMeans, SB3Weights, StackedAdam, StackedMLP, linears, load_params, per_agent

#: the fields of an agent config that name it, not what it trains
_NAMING = ("name", "version", "description")


@dataclass
class SACSettings:
    """What SAC's update reads from its agents' configs: one value for all, or (tuning trials
    stacked in one batch) a ``(K,)`` array where the configs differ (:meth:`for_agents`)."""

    actor_learning_rate: float | np.ndarray
    critic_learning_rate: float | np.ndarray
    alpha: float | np.ndarray
    tau: float | np.ndarray
    gamma: float | np.ndarray
    #: agents whose updates are applied (a pruned trial's are not); None: all
    active: np.ndarray | None = None

    CONTINUOUS: ClassVar[tuple[str, ...]] = ("actor_learning_rate", "critic_learning_rate", "alpha", "tau", "gamma")

    @classmethod
    def for_agents(cls, cfgs: list[Any]) -> SACSettings:
        """The settings of K agents, one config each; everything else (networks, replay, loop)
        must agree (ValueError naming the field)."""
        data = [c.model_dump(mode="json") for c in cfgs]
        for name in data[0]:
            if name not in cls.CONTINUOUS and name not in _NAMING and any(d[name] != data[0][name] for d in data):
                raise ValueError(f"agents of one batch must agree on {name}")
        columns = {name: [float(d[name]) for d in data] for name in cls.CONTINUOUS}
        return cls(**{n: c[0] if len(set(c)) == 1 else np.asarray(c, dtype=np.float64) for n, c in columns.items()})


class StackedSAC(SB3Weights):
    """The K agents' actors (a K-stack), critics and target critics (2K-stacks: agent ``j``'s
    first critic at ``j``, its second at ``K + j``) and their two optimisers, initialised on
    the CPU and moved to ``device``."""

    NETWORKS = ("actor", "critic", "critic_target")
    OPTIMIZERS = ("actor_optimizer", "critic_optimizer")

    def __init__(
        self,
        k: int,
        sizes: list[int],
        actor_lr: float | np.ndarray,
        critic_lr: float | np.ndarray,
        generators: list[th.Generator] | None = None,
        device: th.device | str | None = None,
    ):
        self.k = k
        self.actor = StackedMLP(k, sizes, generators, device)
        self.critic = StackedMLP(2 * k, sizes, None if generators is None else generators + generators, device)
        self.critic_target = StackedMLP(2 * k, sizes, device=device)
        load_params(self.critic_target.params, self.critic.params)
        self.actor_optimizer = StackedAdam(self.actor.params, actor_lr, OFF_POLICY_ADAM_EPS)
        self.critic_optimizer = StackedAdam(self.critic.params, critic_lr, OFF_POLICY_ADAM_EPS)

    def twin_q(self, obs: th.Tensor, target: bool = False) -> tuple[th.Tensor, th.Tensor]:
        """``(Q1, Q2)`` at ``obs (K, B, d)``, each ``(K, B, n_actions)``."""
        q = (self.critic_target if target else self.critic).forward(th.cat([obs, obs]))
        return q[: self.k], q[self.k :]

    def policy(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``(probs, log_probs)`` of the actors at ``obs (K, B, d)``."""
        log_probs = th.log_softmax(self.actor.forward(obs), dim=-1)
        return log_probs.exp(), log_probs

    def sb3_pairs(self, j: int, policy) -> list[tuple[th.Tensor, th.Tensor]]:
        """Agent ``j``'s networks and a ``DiscreteSACPolicy``'s."""
        pairs = self.actor.sb3_pairs(j, linears(policy.actor))
        for net, critic in ((self.critic, policy.critic), (self.critic_target, policy.critic_target)):
            pairs += net.sb3_pairs(j, linears(critic.q1)) + net.sb3_pairs(self.k + j, linears(critic.q2))
        return pairs

    def state_dict(self) -> dict[str, Any]:
        """The networks' parameters and the optimisers' ``state_dict`` (a checkpoint keeps them)."""
        return {
            **{name: list(getattr(self, name).params) for name in self.NETWORKS},
            **{name: getattr(self, name).state_dict() for name in self.OPTIMIZERS},
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Take over :meth:`state_dict` (in place); ValueError if it does not fit."""
        for name in self.NETWORKS:
            load_params(getattr(self, name).params, state[name])
        for name in self.OPTIMIZERS:
            getattr(self, name).load_state_dict(state[name])


def sac_update(
    net: StackedSAC,
    batch: Batch,
    alpha: float | np.ndarray,
    gamma: float | np.ndarray,
    tau: float | np.ndarray,
    means: AgentMeans | None = None,
    active: np.ndarray | None = None,
) -> dict[str, np.ndarray]:
    """One gradient step of :meth:`DiscreteSAC.train` for the K agents: critics, then actor,
    then targets. Returns each agent's critic and actor loss ``(K,)``; they and the mean of
    the twin critics' minimum at the actions taken go to ``means``. ``alpha``, ``gamma``,
    ``tau``: one for all or ``(K,)``; ``active``: the agents whose steps are taken (None: all; the
    learning rates, one or per agent, are the optimisers' own)."""
    alpha_k, gamma_k = per_agent(alpha, batch.rewards, 3), per_agent(gamma, batch.rewards, 2)
    with th.no_grad():
        probs_next, log_probs_next = net.policy(batch.next_obs)
        q1_next, q2_next = net.twin_q(batch.next_obs, target=True)
        v_next = (probs_next * (th.min(q1_next, q2_next) - alpha_k * log_probs_next)).sum(dim=-1)
        y = batch.rewards + gamma_k * (1.0 - batch.dones) * v_next
    q1, q2 = net.twin_q(batch.obs)
    a = batch.actions.unsqueeze(-1)
    q1_taken, q2_taken = q1.gather(-1, a).squeeze(-1), q2.gather(-1, a).squeeze(-1)
    critic_loss = (q1_taken - y).pow(2).mean(dim=1) + (q2_taken - y).pow(2).mean(dim=1)
    net.critic_optimizer.zero_grad()
    critic_loss.sum().backward()
    net.critic_optimizer.step(active=active)

    probs, log_probs = net.policy(batch.obs)
    with th.no_grad():
        q1, q2 = net.twin_q(batch.obs)
        min_q = th.min(q1, q2)
    actor_loss = (probs * (alpha_k * log_probs - min_q)).sum(dim=-1).mean(dim=1)
    net.actor_optimizer.zero_grad()
    actor_loss.sum().backward()
    net.actor_optimizer.step(active=active)

    with th.no_grad():  # SB3's polyak_update: targ * (1 - tau) + tau * online
        # each agent's rate on both its critics' rows, 1 - tau in float64 as for one float tau: an
        # agent's numbers are the same whether its tau comes alone or in a (K,) array
        taus = np.tile(np.broadcast_to(np.asarray(tau, dtype=np.float64), (net.k,)), 2)
        for targ, online in zip(net.critic_target.params, net.critic.params):
            targ.mul_(per_agent(1.0 - taus, targ, targ.ndim)).add_(per_agent(taus, targ, targ.ndim) * online)
    if means is not None:
        q_mean = th.min(q1_taken, q2_taken).mean(dim=1)
        means.add(**{names.VALUE_LOSS: critic_loss, names.ACTOR_LOSS: actor_loss, names.Q_MEAN: q_mean})
    return {"critic_loss": critic_loss.detach().cpu().numpy(), "actor_loss": actor_loss.detach().cpu().numpy()}


class BatchedSAC(BatchedOffPolicyAlgorithm):
    """K discrete-SAC agents (:class:`StackedSAC`): actions drawn from the policy, SAC's update."""

    #: the actor and both target critics at the next states (3), both critics forward and
    #: backward (6), the actor forward and backward (3), both critics for the actor's loss (2)
    FORWARDS_PER_SAMPLE = 14
    PER_AGENT = SACSettings.CONTINUOUS

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device, cfgs: list[Any] | None = None):
        super().__init__(cfg, envs, device, cfgs)
        self.settings = SACSettings.for_agents(self.cfgs)
        self.net = StackedSAC(
            self.k,
            [envs.obs_dim, *cfg.net_arch, 2],
            self.settings.actor_learning_rate,
            self.settings.critic_learning_rate,
            generators=self.init_generators(),
            device=device,
        )

    def act(
        self, obs: np.ndarray, n: int, uniforms: np.ndarray, random_actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        with th.no_grad():
            probs, log_probs = self.net.policy(th.as_tensor(obs, device=self.device).unsqueeze(1))
        probs, log_probs = probs[:, 0].cpu().numpy(), log_probs[:, 0].cpu().numpy()
        actions = random_actions if n < self.cfg.learning_starts else (uniforms < probs[:, 1]).astype(np.int64)
        return actions, -(probs * log_probs).sum(axis=1)

    def greedy(self) -> Greedy:
        return lambda obs: greedy_categorical(self.net.actor.forward(obs))

    def update(self, steps: int, progress_remaining: float, batch: Batch) -> None:
        st = self.settings
        tau = st.tau if st.active is None else np.where(st.active, st.tau, 0.0)  # a frozen agent's targets stay too
        losses = sac_update(self.net, batch, st.alpha, st.gamma, tau, self.means, st.active)
        as_logged = lambda v: th.as_tensor(v, dtype=th.float32) if isinstance(v, np.ndarray) else v  # noqa: E731
        self.means.add(**{names.ENT_COEF: as_logged(st.alpha), names.LEARNING_RATE: as_logged(st.critic_learning_rate)})
        if self.on_update is not None:
            self.on_update({"steps": steps, **losses})
