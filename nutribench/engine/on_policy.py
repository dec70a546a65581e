"""What the batched engine's on-policy algorithms (MC, PPO, GRU-PPO) share: their settings,
the rollout, SB3's GAE, one gradient step on the K agents' losses, and SB3's on-policy loop
(:class:`BatchedOnPolicyAlgorithm`) for K agents stepped together.

Per agent, the loop is SB3's ``PPO.learn`` (MC: ``A2C.learn``; GRU-PPO: ``GRUPPO.learn``,
the GRU state carried from step to step and reset at each day's start) on nutribench's
one-env ``VecNormalize`` setting: observations normalised by a running mean and variance
updated with every observation (including each day's first), rewards scaled by the running
deviation of the discounted return, ``n_steps`` steps per rollout (MC: one day), a day's
end a terminal, then the update. A budget that ends inside a rollout stops there without a
partial update, as SB3 does. Actions are drawn from the policy with each agent's own uniform
draws; the minibatch order of each epoch is each agent's own permutation.

The loop is SB3's three methods: :meth:`~BatchedOnPolicyAlgorithm.learn` (resume from a checkpoint,
then rollouts and updates until the budget, saving :meth:`~BatchedOnPolicyAlgorithm.state_dict` at
rollout boundaries when due), :meth:`~BatchedOnPolicyAlgorithm.collect_rollouts` (``n_steps`` env
steps, reward scaling, a day boundary whenever every agent's day ends, then GAE) and
:meth:`~BatchedOnPolicyAlgorithm.train` (the algorithm's update on one rollout, then its
diagnostics). An algorithm subclass gives its network
(:meth:`~BatchedOnPolicyAlgorithm.make_network`), its acting (:meth:`~BatchedOnPolicyAlgorithm.make_actor`:
a callable ``(obs, starts, advance)`` -> ``(logits, values)``) and its ``train``. After each
update every agent gets one diagnostics dict, each value what SB3's logger records for that
agent's update: the means over the update's gradient steps of its losses, gradient norm and
clip fraction, PPO's approximate KL over the last epoch's minibatches (``train/approx_kl``),
the rollout's explained variance, the learning rate and, with reward normalisation, the
return scale.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields
from typing import Any, ClassVar

import numpy as np
import torch as th
from stable_baselines3.common.utils import explained_variance

from nutribench import diagnostics as names
from nutribench.agents.algos import model_arguments
from nutribench.agents.api import CLIP_OBS, NORM_EPS
from nutribench.engine.algorithm import BatchedAlgorithm
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.envs import AgentEnvs
from nutribench.engine.stacked import (
    AgentMeans,
    RunningStats,
    StackedAdam,
    clip_grad_norm_per_agent,
    load_params,
    per_agent,
)

ADAM_EPS = 1e-5  # SB3's ActorCriticPolicy passes eps=1e-5 to Adam


@dataclass
class OnPolicySettings:
    """What the rollout and the update read from an agent config (PPO, MC or GRU-PPO): the
    one place the on-policy loop and updates take their settings from (never the config).
    Each continuous setting is one float for all K agents, read only in :func:`gradient_step`
    (``ent_coef``, ``vf_coef``, ``max_grad_norm``), :func:`~nutribench.engine.ppo.ppo_update`
    (``clip_range``), :meth:`BatchedOnPolicyAlgorithm.scale_rewards` (``gamma``),
    :meth:`BatchedOnPolicyAlgorithm.compute_returns` (``gamma``, ``gae_lambda``), the optimiser
    (:class:`~nutribench.engine.stacked.StackedAdam`) and :meth:`BatchedOnPolicyAlgorithm.log_update`
    (``learning_rate``), so a per-agent value (a ``(K,)`` array) changes those reads only."""

    learning_rate: float | np.ndarray
    n_steps: int
    batch_size: int
    n_epochs: int
    gamma: float | np.ndarray
    gae_lambda: float | np.ndarray
    clip_range: float | np.ndarray | None  # None: A2C's update (MC)
    ent_coef: float | np.ndarray
    vf_coef: float | np.ndarray
    max_grad_norm: float | np.ndarray
    normalize_advantage: bool
    sequence_length: int | None = None  # GRU-PPO: minibatches of whole days (batch_size counts days)
    #: agents whose updates are applied (``(K,)`` bool, the caller's array, read at every step);
    #: None: all. A frozen agent's parameters stay as they are (a pruned tuning trial's).
    active: np.ndarray | None = None

    #: the settings that may differ between the agents of one batch (each a ``(K,)`` array then)
    CONTINUOUS: ClassVar[tuple[str, ...]] = (
        "learning_rate",
        "gamma",
        "gae_lambda",
        "clip_range",
        "ent_coef",
        "vf_coef",
        "max_grad_norm",
    )

    @classmethod
    def for_agents(cls, cfgs: list[Any], horizon: int) -> OnPolicySettings:
        """The settings of K agents, one config each: the structural settings must agree (they
        shape the rollout and the minibatches); each continuous one (:attr:`CONTINUOUS`) is a
        ``(K,)`` array where the configs differ, else the one value (the single-config path,
        unchanged)."""
        each = [cls.from_config(c, horizon) for c in cfgs]
        first = each[0]
        for name in first.__dataclass_fields__:
            values = [getattr(e, name) for e in each]
            if name == "active" or len(set(values)) == 1:
                continue
            if name not in cls.CONTINUOUS:
                raise ValueError(f"agents of one batch must agree on {name} (got {sorted(set(values), key=str)})")
            setattr(first, name, np.asarray(values, dtype=np.float64))
        return first

    @classmethod
    def from_config(cls, cfg: Any, horizon: int) -> OnPolicySettings:
        """The settings of the SB3 model that ``algos.model_arguments`` builds for ``cfg``
        on days of ``horizon`` steps: the fields its arguments name, as written (PPO's); MC's as
        A2C gets them (a rollout of one day, one step on all of it, lambda 1, no advantage
        normalisation); GRU-PPO's batch in whole days (as ``GRUPPO.sequences_per_batch``)."""
        _, args = model_arguments(cfg, horizon)
        settings = {"n_epochs": 1, "clip_range": None}  # A2C's (MC's): one pass, no clipping
        settings |= {f.name: args[f.name] for f in fields(cls) if f.name in args}
        seq = args.get("sequence_length")
        batch_size = args.get("batch_size", args["n_steps"])
        settings["batch_size"] = batch_size if seq is None else max(1, round(batch_size / seq))
        return cls(**settings, gamma=cfg.gamma)


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
    gamma: float | np.ndarray,
    lam: float | np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """SB3's ``RolloutBuffer.compute_returns_and_advantage`` for ``(K, T)`` arrays: advantages,
    returns (``gamma``, ``lam``: one for all, or ``(K,)``)."""
    k, t_max = rewards.shape
    # gamma * lam in float64 as two float settings multiply, then each factor float32 as a float
    # setting is against a float32 array (numpy's weak scalars): one agent's numbers are the
    # same whether its settings come as floats or as a (K,) array beside other agents'
    gamma_lam = np.multiply(gamma, lam, dtype=np.float64)
    if gamma_lam.ndim:
        gamma = np.broadcast_to(gamma, (k,)).astype(np.float32)
        gamma_lam = np.broadcast_to(gamma_lam, (k,)).astype(np.float32)
    else:  # a Python float: a np.float64 would not be weak, and would turn the arrays float64
        gamma_lam = float(gamma_lam)
    adv = np.zeros((k, t_max), dtype=np.float32)
    last = np.zeros(k, dtype=np.float32)
    # each step's successor: the next step's value and start, after the last step the values after the rollout
    next_values = np.concatenate([values[:, 1:], last_values[:, None]], axis=1)
    non_terminal = 1.0 - np.concatenate([episode_starts[:, 1:], last_dones.astype(np.float32)[:, None]], axis=1)
    for t in reversed(range(t_max)):
        delta = rewards[:, t] + gamma * next_values[:, t] * non_terminal[:, t] - values[:, t]
        last = delta + gamma_lam * non_terminal[:, t] * last
        adv[:, t] = last
    return adv, adv + values


def log_prob_entropy(logits: th.Tensor, actions: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
    """``log pi(a|s)`` and the categorical policy's entropy from ``logits (K, B, n_actions)``
    and ``actions (K, B)``, each ``(K, B)``."""
    logp_all = th.log_softmax(logits, dim=-1)
    log_prob = logp_all.gather(-1, actions.unsqueeze(-1)).squeeze(-1)
    entropy = -(logp_all.exp() * logp_all).sum(-1)
    return log_prob, entropy


def normalized(adv: th.Tensor) -> th.Tensor:
    """Advantages ``(K, B)`` normalised per agent (SB3's ``normalize_advantage``)."""
    return (adv - adv.mean(dim=1, keepdim=True)) / (adv.std(dim=1, keepdim=True) + 1e-8)


def gradient_step(
    params: list[th.Tensor],
    optimizer: StackedAdam,
    settings: OnPolicySettings,
    policy_loss: th.Tensor,
    value_loss: th.Tensor,
    entropy_loss: th.Tensor,
    k: int | None = None,
    means: AgentMeans | None = None,
) -> None:
    """One gradient step on the K agents' losses ``(K,)``: SB3's weighting, per-agent clipping
    (``k``: as :func:`~nutribench.engine.stacked.clip_grad_norm_per_agent`), each agent's own
    coefficients and learning rate where they differ (:meth:`OnPolicySettings.for_agents`);
    the losses and the gradient norms go to ``means``."""
    ent_coef, vf_coef = per_agent(settings.ent_coef, policy_loss), per_agent(settings.vf_coef, policy_loss)
    loss = policy_loss + ent_coef * entropy_loss + vf_coef * value_loss
    optimizer.zero_grad()
    loss.sum().backward()  # disjoint parameters: each agent gets its own loss's gradient
    norms = clip_grad_norm_per_agent(params, settings.max_grad_norm, k)
    optimizer.step(active=settings.active)
    if means is not None:
        losses = {names.POLICY_LOSS: policy_loss, names.VALUE_LOSS: value_loss, names.ENTROPY_LOSS: entropy_loss}
        means.add(**losses, **{names.GRAD_NORM: norms})


class StackedActor:
    """Acting with ``net`` (its ``step(obs (K, d), state, starts (K,))`` -> logits ``(K, n_actions)``,
    values ``(K,)``, the new state): ``state`` (a recurrent net's; None: a feedforward net keeps
    none) carried from step to step, reset by the net where a day starts; ``advance=False``
    peeks (the value after the rollout, as SB3's ``predict_values``, which does not keep the
    new state)."""

    def __init__(self, net: Any, state: th.Tensor | None = None):
        self.net, self.state = net, state

    def __call__(self, obs: th.Tensor, starts: th.Tensor, advance: bool = True) -> tuple[th.Tensor, th.Tensor]:
        logits, values, state = self.net.step(obs, self.state, starts)
        if advance:
            self.state = state
        return logits, values

    def state_dict(self) -> dict[str, th.Tensor]:
        """The carried state (a checkpoint keeps it; nothing for a feedforward actor)."""
        return {} if self.state is None else {"state": self.state}

    def load_state_dict(self, state: dict[str, th.Tensor]) -> None:
        if self.state is None:
            return
        if state["state"].shape != self.state.shape:
            raise ValueError("the checkpoint's GRU state does not fit this batch")
        self.state = state["state"].to(self.state.device)


class BatchedOnPolicyAlgorithm(BatchedAlgorithm):
    """SB3's on-policy loop for the K agents of ``envs`` (the module docstring); subclasses
    give the network, the acting and :meth:`train`."""

    PER_AGENT = OnPolicySettings.CONTINUOUS

    @classmethod
    def forward_flops(cls, cfg: Any, obs_dim: int, n_actions: int) -> float:
        """Matrix-product FLOPs of one sample's forward pass through the network."""
        raise NotImplementedError

    @classmethod
    def flops_per_env_step(cls, cfg: Any, obs_dim: int = 13, n_actions: int = 2, horizon: int = 50) -> float:
        """Matrix-product FLOPs per env step: one forward to act, and per step of the rollout
        ``n_epochs`` forward + backward passes (a backward as 2 forwards)."""
        forward = cls.forward_flops(cfg, obs_dim, n_actions)
        return forward * (1 + 3 * OnPolicySettings.from_config(cfg, horizon).n_epochs)

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device, cfgs: list[Any] | None = None):
        super().__init__(cfg, envs, device, cfgs)
        self.settings = OnPolicySettings.for_agents(self.cfgs, envs.horizon)
        self.net = self.make_network(self.init_generators())
        self.actor = self.make_actor(self.net)
        self.optimizer = StackedAdam(self.net.params, self.settings.learning_rate, ADAM_EPS)
        self.ret_stats = RunningStats(self.k) if cfg.normalize_reward else None
        self.discounted = np.zeros(self.k)  # each agent's discounted return so far (reward scaling)
        #: whether the step the agents act on next (at :attr:`last_obs`) starts a day (SB3's
        #: ``_last_obs``, ``_last_episode_starts``)
        self.start_of_day = np.ones(self.k, dtype=np.float32)

    # ---- what each algorithm gives ----

    def make_network(self, generators: list[th.Generator]) -> Any:
        """The K agents' stacked network (``params``, ``store_sb3``), initialised from ``generators``."""
        raise NotImplementedError

    def make_actor(self, net: Any) -> StackedActor:
        """Acting with ``net``: ``(obs (K, d), starts (K,), advance=True)`` -> logits, values
        (here: a feedforward net's, no state)."""
        return StackedActor(net)

    def train(self, rollout: Rollout) -> None:
        """The algorithm's update of the K agents on ``rollout`` (SB3's ``train()``), then
        :meth:`log_update`."""
        raise NotImplementedError

    # ---- the loop ----

    def learn(self, total_steps: int, checkpoint: Checkpoint | None = None) -> float:
        seconds_before = self.resume(checkpoint)
        if self.last_obs is None:
            self.last_obs = self.envs.seen(self.envs.new_days())
        first, t0 = self.num_timesteps, time.perf_counter()
        while self.num_timesteps < total_steps:
            if checkpoint is not None and self.num_timesteps > first and checkpoint.due():
                checkpoint.save(**self.state_dict())
            rollout = self.collect_rollouts(min(self.settings.n_steps, total_steps - self.num_timesteps))
            if rollout is None:
                break  # a partial rollout: SB3 stops without updating on it
            self.train(rollout)
        return time.perf_counter() - t0 + seconds_before

    def collect_rollouts(self, n_steps: int) -> Rollout | None:
        """``n_steps`` env steps of every agent from :attr:`last_obs`; the rollout with its
        advantages and returns, or None for a rollout shorter than ``settings.n_steps`` (the
        budget's end)."""
        envs, k = self.envs, self.k
        buf = {name: np.empty((k, n_steps), dtype=np.float32) for name in ("log_probs", "values", "rewards", "starts")}
        buf["obs"] = np.empty((k, n_steps, envs.obs_dim), dtype=np.float32)
        buf["actions"] = np.empty((k, n_steps), dtype=np.int64)
        uniforms = np.stack([r.random(n_steps) for r in envs.rng["actions"]])
        obs, start_of_day = self.last_obs, self.start_of_day
        for t in range(n_steps):
            self.day_boundary(self.num_timesteps)  # the evaluation during training that is due, if any
            logits, values = self.act(obs, start_of_day)
            logp = th.log_softmax(logits, dim=-1).cpu().numpy()
            actions = (uniforms[:, t] < np.exp(logp[:, 1])).astype(np.int64)
            buf["obs"][:, t], buf["actions"][:, t], buf["starts"][:, t] = obs, actions, start_of_day
            buf["log_probs"][:, t] = logp[np.arange(k), actions]
            buf["values"][:, t] = values.cpu().numpy()
            raw_next, rewards, day_over = envs.step(actions, entropy=-(np.exp(logp) * logp).sum(axis=1))
            buf["rewards"][:, t] = self.scale_rewards(rewards)
            self.num_timesteps += 1
            start_of_day = np.full(k, float(day_over), dtype=np.float32)
            if day_over:  # a day boundary: every agent's day ended at this step
                self.discounted[:] = 0.0
                raw_next = envs.new_days()
            obs = envs.seen(raw_next)
        self.last_obs, self.start_of_day = obs, start_of_day
        return None if n_steps < self.settings.n_steps else self.compute_returns(buf)

    def act(self, obs: np.ndarray, starts: np.ndarray, advance: bool = True) -> tuple[th.Tensor, th.Tensor]:
        """:attr:`actor` (no gradient) at the env's observations ``obs (K, d)`` and day starts ``(K,)``."""
        with th.no_grad():
            return self.actor(th.as_tensor(obs, device=self.device), th.as_tensor(starts, device=self.device), advance)

    def scale_rewards(self, rewards: np.ndarray) -> np.ndarray:
        """``VecNormalize``'s reward scaling: the running deviation of each agent's discounted
        return, updated with this step's rewards (the rewards as they are without it)."""
        if self.ret_stats is None:
            return rewards
        self.discounted = self.discounted * self.settings.gamma + rewards
        self.ret_stats.update(self.discounted)
        return np.clip(rewards / np.sqrt(self.ret_stats.var + NORM_EPS), -CLIP_OBS, CLIP_OBS)

    def compute_returns(self, buf: dict[str, np.ndarray]) -> Rollout:
        """The rollout of ``buf`` (the arrays of :meth:`collect_rollouts`) with SB3's GAE
        from the value after its last step; handed to ``on_rollout`` first, if set."""
        _, last_values = self.act(self.last_obs, self.start_of_day, advance=False)
        last, dones = last_values.cpu().numpy(), self.start_of_day.astype(bool)
        buf["advantages"], buf["returns"] = gae(
            buf["rewards"], buf["values"], buf["starts"], last, dones, self.settings.gamma, self.settings.gae_lambda
        )
        if self.on_rollout is not None:
            shown = ("obs", "actions", "rewards", "starts", "values", "advantages", "returns")
            self.on_rollout({**{name: buf[name] for name in shown}, "foods": np.stack(self.envs.days_drawn)})
        return Rollout(**{f.name: th.as_tensor(buf[f.name], device=self.device) for f in fields(Rollout)})

    def permutations(self, rollout: Rollout) -> np.ndarray:
        """``(n_epochs, K, units)``: each agent's order of the rollout's units (transitions, or
        GRU-PPO's whole days) in each epoch, from its own stream (SB3 draws ``np.random.permutation``
        once per epoch)."""
        units = rollout.actions.shape[1] // (self.settings.sequence_length or 1)
        streams = self.envs.rng["minibatches"]
        return np.stack([[r.permutation(units) for r in streams] for _ in range(self.settings.n_epochs)])

    def log_update(self, rollout: Rollout) -> None:
        """The diagnostics of the update just made on ``rollout`` (one read of the device's sums)."""
        means = self.means.means()
        values, returns = rollout.values.cpu().numpy(), rollout.returns.cpu().numpy()
        variances = [explained_variance(v, r) for v, r in zip(values, returns)]
        row = {**means, names.EXPLAINED_VARIANCE: variances, names.LEARNING_RATE: self.settings.learning_rate}
        if self.ret_stats is not None:
            row[names.RETURN_SCALE] = np.sqrt(self.ret_stats.var + NORM_EPS)
        self.record(self.num_timesteps, row)

    # ---- its state ----

    def state_dict(self) -> dict[str, Any]:
        return {
            **super().state_dict(),
            "obs": self.last_obs,
            "start_of_day": self.start_of_day,
            "params": list(self.net.params),
            "actor": self.actor.state_dict(),
            "optimizer": self.optimizer.state_dict(),
            "ret_stats": None if self.ret_stats is None else self.ret_stats.state_dict(),
            "discounted": self.discounted,
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        load_params(self.net.params, state["params"])
        self.actor.load_state_dict(state["actor"])
        self.optimizer.load_state_dict(state["optimizer"])
        if self.ret_stats is not None:
            self.ret_stats.load_state_dict(state["ret_stats"])
        self.discounted = np.asarray(state["discounted"], dtype=np.float64)
        self.last_obs = np.asarray(state["obs"], dtype=np.float32)
        self.start_of_day = np.asarray(state["start_of_day"], dtype=np.float32)
