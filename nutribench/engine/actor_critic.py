"""PPO and MC for K agents at once: SB3's updates, with every agent's parameters stacked
along a leading agent axis.

The K agents share an agent config (``ppo.toml`` or ``mc.toml``) and differ in their seed
(and may differ in their regime: each agent has its own env row). Per agent, everything is
what :class:`stable_baselines3.PPO` (MC: :class:`~nutribench.agents.algos.MonteCarloAC`, an
A2C) with nutribench's shared backbone does (``algos.build_model``):

* policy: ``obs -> 256 -> 128`` (ReLU) shared by a linear actor head (2 logits) and a linear
  value head; orthogonal initialisation with SB3's gains (sqrt(2) backbone, 0.01 actor, 1
  value), zero biases; Adam with eps 1e-5;
* ``VecNormalize``: a running mean and variance of the observations, and of the discounted
  return for reward scaling, each agent its own;
* rollouts of ``n_steps`` env steps, GAE (gamma, lambda), a day's end a true terminal;
* PPO: ``n_epochs`` passes over the rollout in minibatches of ``batch_size`` drawn by a random
  permutation; advantages normalised per minibatch; clipped surrogate; unclipped value loss;
  entropy bonus; the gradient clipped to ``max_grad_norm`` in L2 over the agent's own
  parameters;
* MC (A2C's update): one rollout of one day (GAE lambda 1: full-episode returns), one
  gradient step on all of it: ``-(advantage * log pi)`` + value MSE + entropy bonus, no
  clipping when ``max_grad_norm`` is ``inf``.

Stacking is exact: the loss is the sum of the K agents' losses, so each agent's gradient is
its own loss's gradient; Adam is elementwise; the gradient norm is taken per agent. One
update of agent k equals SB3's update of that agent alone (``tests/test_engine.py``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch as th

from nutribench.engine.device import leaves_on

ADAM_EPS = 1e-5  # SB3's ActorCriticPolicy passes eps=1e-5 to Adam
GAINS = (math.sqrt(2), math.sqrt(2), 0.01, 1.0)  # backbone layers, actor head, value head


@dataclass
class OnPolicySettings:
    """What the rollout and the update read from an agent config (PPO, MC or GRU-PPO)."""

    algo: str
    learning_rate: float
    n_steps: int
    batch_size: int
    n_epochs: int
    gamma: float
    gae_lambda: float
    clip_range: float | None  # None: A2C's update (MC)
    ent_coef: float
    vf_coef: float
    max_grad_norm: float
    normalize_advantage: bool
    sequence_length: int | None = None  # GRU-PPO: minibatches of whole days (batch_size counts days)

    @classmethod
    def from_config(cls, cfg, horizon: int) -> OnPolicySettings:
        """PPO's fields as written; MC as ``algos.model_arguments`` builds it: a rollout of one
        day, one step on all of it, lambda 1, no advantage normalisation; GRU-PPO's batch in
        whole days."""
        common = dict(
            algo=cfg.algo,
            learning_rate=cfg.learning_rate,
            gamma=cfg.gamma,
            ent_coef=cfg.ent_coef,
            vf_coef=cfg.vf_coef,
            max_grad_norm=cfg.max_grad_norm,
        )
        if cfg.algo == "mc":
            return cls(
                **common,
                n_steps=horizon,
                batch_size=horizon,
                n_epochs=1,
                gae_lambda=1.0,
                clip_range=None,
                normalize_advantage=False,
            )
        if cfg.algo == "ppo":
            return cls(
                **common,
                n_steps=cfg.n_steps,
                batch_size=cfg.batch_size,
                n_epochs=cfg.n_epochs,
                gae_lambda=cfg.gae_lambda,
                clip_range=cfg.clip_range,
                normalize_advantage=cfg.normalize_advantage,
            )
        if cfg.algo == "gru_ppo":  # as GRUPPO.sequences_per_batch
            return cls(
                **common,
                n_steps=cfg.n_steps,
                batch_size=max(1, round(cfg.batch_size / cfg.sequence_length)),
                n_epochs=cfg.n_epochs,
                gae_lambda=cfg.gae_lambda,
                clip_range=cfg.clip_range,
                normalize_advantage=cfg.normalize_advantage,
                sequence_length=cfg.sequence_length,
            )
        raise ValueError(f"no on-policy settings for {cfg.algo!r}")

    def update(
        self, net: StackedActorCritic, optimizer: th.optim.Optimizer, rollout: Rollout, permutations: np.ndarray
    ) -> dict[str, np.ndarray]:
        """The algorithm's update of the K agents on one rollout."""
        if self.clip_range is None:
            return a2c_update(net, optimizer, rollout, self)
        return ppo_update(net, optimizer, rollout, self, permutations)


def orthogonal(k: int, n_in: int, n_out: int, gain: float, generators: list[th.Generator] | None = None) -> th.Tensor:
    """``(k, n_in, n_out)``: each agent's ``(n_out, n_in)`` weight initialised orthogonally as
    SB3 (and ``GRUActorCriticPolicy``) do, from its own generator, then transposed."""
    w = th.empty(k, n_in, n_out)
    for j in range(k):
        block = th.empty(n_out, n_in)
        th.nn.init.orthogonal_(block, gain=gain, generator=None if generators is None else generators[j])
        w[j] = block.T
    return w


def linears(module: th.nn.Module) -> list[th.nn.Linear]:
    """The ``Linear`` layers of an ``nn.Sequential`` MLP, input to output."""
    return [m for m in module if isinstance(m, th.nn.Linear)]


class StackedActorCritic:
    """K copies of the shared actor-critic: parameters of shape ``(K, ...)``.

    Layers are ``(W, b)`` with ``W: (K, in, out)``, ``b: (K, 1, out)``: the backbone's layers,
    then one head layer holding the actor's logits and the value side by side (columns
    ``:n_actions`` and ``n_actions``), so that both heads are one batched product.
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
        self.n_actions = n_actions
        self.n_hidden = len(net_arch)
        self.params: list[th.Tensor] = []

        for n_in, n_out in zip(sizes[:-1], sizes[1:]):
            self.params += [
                orthogonal(k, n_in, n_out, GAINS[0], generators).requires_grad_(),
                th.zeros(k, 1, n_out, requires_grad=True),
            ]
        head = th.cat(
            [
                orthogonal(k, sizes[-1], n_actions, GAINS[2], generators),
                orthogonal(k, sizes[-1], 1, GAINS[3], generators),
            ],
            dim=2,
        )
        self.params += [head.requires_grad_(), th.zeros(k, 1, n_actions + 1, requires_grad=True)]
        self.params = leaves_on(self.params, device)

    @property
    def k(self) -> int:
        return self.params[0].shape[0]

    def forward(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``obs (K, B, obs_dim)`` -> logits ``(K, B, n_actions)``, values ``(K, B)``."""
        x = obs
        p = self.params
        for i in range(self.n_hidden):
            x = th.relu(th.baddbmm(p[2 * i + 1], x, p[2 * i]))
        out = th.baddbmm(p[-1], x, p[-2])
        return out[..., : self.n_actions], out[..., self.n_actions]

    def load_sb3(self, j: int, policy) -> None:
        """Copy the weights of an SB3 ``ActorCriticPolicy`` (nutribench's backbone) into agent ``j``."""
        with th.no_grad():
            for i, lin in enumerate(linears(policy.features_extractor.net)):
                self.params[2 * i][j].copy_(lin.weight.T)
                self.params[2 * i + 1][j, 0].copy_(lin.bias)
            self.params[-2][j].copy_(th.cat([policy.action_net.weight, policy.value_net.weight]).T)
            self.params[-1][j, 0].copy_(th.cat([policy.action_net.bias, policy.value_net.bias]))

    def store_sb3(self, j: int, policy) -> None:
        """Copy agent ``j``'s weights into an SB3 ``ActorCriticPolicy`` of the same shape."""
        a = self.n_actions
        with th.no_grad():
            for i, lin in enumerate(linears(policy.features_extractor.net)):
                lin.weight.copy_(self.params[2 * i][j].T)
                lin.bias.copy_(self.params[2 * i + 1][j, 0])
            policy.action_net.weight.copy_(self.params[-2][j][:, :a].T)
            policy.value_net.weight.copy_(self.params[-2][j][:, a:].T)
            policy.action_net.bias.copy_(self.params[-1][j, 0, :a])
            policy.value_net.bias.copy_(self.params[-1][j, 0, a:])


class RunningStats:
    """SB3's ``RunningMeanStd`` for K agents at once: ``mean``/``var`` ``(K, *shape)``,
    ``count (K,)``, each agent updated with one sample ``(K, *shape)`` per call."""

    def __init__(self, k: int, shape: tuple[int, ...] = (), epsilon: float = 1e-4):
        self.mean = np.zeros((k, *shape))
        self.var = np.ones((k, *shape))
        self.count = np.full(k, epsilon)

    def update(self, x: np.ndarray) -> None:
        """One sample per agent (SB3's update with a batch of one: batch variance 0)."""
        c = self.count.reshape(-1, *([1] * (self.mean.ndim - 1)))
        delta = x - self.mean
        tot = c + 1.0
        self.mean = self.mean + delta / tot
        self.var = (self.var * c + np.square(delta) * c / tot) / tot
        self.count = self.count + 1.0


def clip_grad_norm_per_agent(params: list[th.Tensor], max_norm: float, k: int | None = None) -> th.Tensor:
    """``torch.nn.utils.clip_grad_norm_`` applied to each agent's own parameters; the K norms.
    A parameter may stack several networks per agent along its first axis (``m * K`` rows:
    row ``i * K + j`` is agent ``j``'s ``i``-th); ``k`` is K (default: the first parameter's rows)."""
    k = params[0].shape[0] if k is None else k
    sq = sum(p.grad.pow(2).reshape(p.shape[0] // k, k, -1).sum(dim=(0, 2)) for p in params)
    norms = sq.sqrt()
    if math.isfinite(max_norm):
        coef = (max_norm / (norms + 1e-6)).clamp(max=1.0)
        for p in params:
            p.grad.mul_(coef.repeat(p.shape[0] // k).reshape(-1, *([1] * (p.ndim - 1))))
    return norms


@dataclass
class Rollout:
    """One rollout of K agents, ``T`` steps each (agent axis first)."""

    obs: th.Tensor  # (K, T, obs_dim) as the policy saw them (normalised)
    actions: th.Tensor  # (K, T) long
    log_probs: th.Tensor  # (K, T)
    values: th.Tensor  # (K, T)
    advantages: th.Tensor  # (K, T)
    returns: th.Tensor  # (K, T)


def gae(
    rewards: np.ndarray,
    values: np.ndarray,
    episode_starts: np.ndarray,
    last_values: np.ndarray,
    last_dones: np.ndarray,
    gamma: float,
    lam: float,
) -> tuple[np.ndarray, np.ndarray]:
    """SB3's ``RolloutBuffer.compute_returns_and_advantage`` for ``(K, T)`` arrays: advantages, returns."""
    k, t_max = rewards.shape
    adv = np.zeros((k, t_max), dtype=np.float32)
    last = np.zeros(k, dtype=np.float32)
    for t in reversed(range(t_max)):
        if t == t_max - 1:
            non_terminal = 1.0 - last_dones.astype(np.float32)
            next_values = last_values
        else:
            non_terminal = 1.0 - episode_starts[:, t + 1]
            next_values = values[:, t + 1]
        delta = rewards[:, t] + gamma * next_values * non_terminal - values[:, t]
        last = delta + gamma * lam * non_terminal * last
        adv[:, t] = last
    return adv, adv + values


def ppo_update(
    net: StackedActorCritic,
    optimizer: th.optim.Optimizer,
    rollout: Rollout,
    s: OnPolicySettings,
    permutations: np.ndarray,
) -> dict[str, np.ndarray]:
    """SB3 ``PPO.train()`` for the K agents: ``permutations (n_epochs, K, T)`` order each
    agent's transitions in each epoch (SB3 draws ``np.random.permutation(T)``). Returns the
    last minibatch's per-agent losses."""
    k, t_max = rollout.actions.shape
    device = rollout.actions.device
    rows = th.arange(k, device=device).unsqueeze(1)
    out: dict[str, np.ndarray] = {}
    for epoch in range(s.n_epochs):
        perm = th.as_tensor(permutations[epoch], device=device)
        # the epoch's order once, then contiguous minibatches of it (SB3's order exactly)
        obs_e, act_e, adv_e = rollout.obs[rows, perm], rollout.actions[rows, perm], rollout.advantages[rows, perm]
        logp_e, ret_e = rollout.log_probs[rows, perm], rollout.returns[rows, perm]
        for start in range(0, t_max, s.batch_size):
            mb = slice(start, start + s.batch_size)
            adv = adv_e[:, mb]
            if s.normalize_advantage and adv.shape[1] > 1:
                adv = (adv - adv.mean(dim=1, keepdim=True)) / (adv.std(dim=1, keepdim=True) + 1e-8)
            log_prob, entropy, values = _evaluate_actions(net, obs_e[:, mb], act_e[:, mb])
            ratio = th.exp(log_prob - logp_e[:, mb])
            surrogate = th.min(adv * ratio, adv * th.clamp(ratio, 1 - s.clip_range, 1 + s.clip_range))
            policy_loss = -surrogate.mean(dim=1)
            value_loss = (ret_e[:, mb] - values).pow(2).mean(dim=1)
            out = _step(net, optimizer, s, policy_loss, value_loss, -entropy.mean(dim=1))
    return out


def a2c_update(
    net: StackedActorCritic, optimizer: th.optim.Optimizer, rollout: Rollout, s: OnPolicySettings
) -> dict[str, np.ndarray]:
    """SB3 ``A2C.train()`` for the K agents: one gradient step on the whole rollout (MC)."""
    log_prob, entropy, values = _evaluate_actions(net, rollout.obs, rollout.actions)
    adv = rollout.advantages
    if s.normalize_advantage:
        adv = (adv - adv.mean(dim=1, keepdim=True)) / (adv.std(dim=1, keepdim=True) + 1e-8)
    policy_loss = -(adv * log_prob).mean(dim=1)
    value_loss = (rollout.returns - values).pow(2).mean(dim=1)
    return _step(net, optimizer, s, policy_loss, value_loss, -entropy.mean(dim=1))


def _evaluate_actions(
    net: StackedActorCritic, obs: th.Tensor, actions: th.Tensor
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """``log pi(a|s)``, the policy's entropy and the values, each ``(K, B)``."""
    logits, values = net.forward(obs)
    logp_all = th.log_softmax(logits, dim=-1)
    log_prob = logp_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    entropy = -(logp_all.exp() * logp_all).sum(-1)
    return log_prob, entropy, values


def _step(
    net: StackedActorCritic,
    optimizer: th.optim.Optimizer,
    s: OnPolicySettings,
    policy_loss: th.Tensor,
    value_loss: th.Tensor,
    entropy_loss: th.Tensor,
) -> dict[str, np.ndarray]:
    """One gradient step on the K agents' losses ``(K,)``: SB3's weighting, per-agent clipping."""
    loss = policy_loss + s.ent_coef * entropy_loss + s.vf_coef * value_loss
    optimizer.zero_grad()
    loss.sum().backward()  # disjoint parameters: each agent gets its own loss's gradient
    clip_grad_norm_per_agent(net.params, s.max_grad_norm)
    optimizer.step()
    return losses_on_cpu(policy_loss=policy_loss, value_loss=value_loss, entropy_loss=entropy_loss)


def losses_on_cpu(**losses: th.Tensor) -> dict[str, np.ndarray]:
    """The K agents' losses as numpy arrays (from any device)."""
    return {name: loss.detach().cpu().numpy() for name, loss in losses.items()}


def make_adam(params: list[th.Tensor], learning_rate: float, eps: float) -> th.optim.Adam:
    """Adam over stacked parameters (elementwise, so each agent's update is its own), in
    torch's fused form where this torch has it for the CPU (2.4 and later): the per-tensor
    Adam's formula in one kernel per step, equal to float32 rounding (on this CPU 0.3 ms a
    step instead of 3.9 ms for K = 35)."""
    try:
        return th.optim.Adam(params, lr=learning_rate, eps=eps, fused=True)
    except RuntimeError:  # pragma: no cover - torch < 2.4 on CPU
        return th.optim.Adam(params, lr=learning_rate, eps=eps, foreach=True)


def make_optimizer(net, learning_rate: float) -> th.optim.Adam:
    """The on-policy agents' Adam (SB3's actor-critic policies: eps 1e-5) over ``net.params``."""
    return make_adam(net.params, learning_rate, ADAM_EPS)
