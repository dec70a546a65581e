"""What the batched engine's on-policy algorithms (MC, PPO, GRU-PPO) share: their settings,
the rollout, SB3's GAE, one gradient step on the K agents' losses, and SB3's on-policy loop
(:class:`OnPolicyAlgorithm`) for K agents stepped together.

Per agent, the loop is SB3's ``PPO.learn`` (MC: ``A2C.learn``; GRU-PPO: ``GRUPPO.learn``,
the GRU state carried from step to step and reset at each day's start) on nutribench's
one-env ``VecNormalize`` setting: observations normalised by a running mean and variance
updated with every observation (including each day's first), rewards scaled by the running
deviation of the discounted return, ``n_steps`` steps per rollout (MC: one day), a day's
end a terminal, then the update. A budget that ends inside a rollout stops there without a
partial update, as SB3 does. Actions are drawn from the policy with each agent's own uniform
draws; the minibatch order of each epoch is each agent's own permutation.

An algorithm subclass gives its network (:meth:`OnPolicyAlgorithm.make_network`), its
acting (:meth:`~OnPolicyAlgorithm.make_actor`: a callable ``(obs, starts, advance)`` ->
``(logits, values)``), what a permutation orders (:meth:`~OnPolicyAlgorithm.units`:
transitions, or whole days) and its update (:meth:`~OnPolicyAlgorithm.update`). After each
update every agent gets one diagnostics dict: the means over the update's gradient steps of
its losses and gradient norm (and PPO's approximate KL and clip fraction), the rollout's
explained variance, the learning rate and, with reward normalisation, the return scale.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from nutribench import diagnostics as names
from nutribench.agents.algos import model_arguments
from nutribench.agents.api import CLIP_OBS, NORM_EPS
from nutribench.engine.algorithm import Algorithm
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.envs import AgentEnvs
from nutribench.engine.stacked import AgentMeans, RunningStats, clip_grad_norm_per_agent, explained_variance, make_adam

ADAM_EPS = 1e-5  # SB3's ActorCriticPolicy passes eps=1e-5 to Adam


@dataclass
class OnPolicySettings:
    """What the rollout and the update read from an agent config (PPO, MC or GRU-PPO)."""

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
    def from_config(cls, cfg: Any, horizon: int) -> OnPolicySettings:
        """The settings of the SB3 model that ``algos.model_arguments`` builds for ``cfg``
        on days of ``horizon`` steps: PPO's fields as written; MC's as A2C gets them (a
        rollout of one day, one step on all of it, lambda 1, no advantage normalisation);
        GRU-PPO's batch in whole days (as ``GRUPPO.sequences_per_batch``)."""
        _, args = model_arguments(cfg, horizon)
        seq = args.get("sequence_length")
        batch_size = args.get("batch_size", args["n_steps"])
        return cls(
            learning_rate=args["learning_rate"],
            n_steps=args["n_steps"],
            batch_size=batch_size if seq is None else max(1, round(batch_size / seq)),
            n_epochs=args.get("n_epochs", 1),
            gamma=cfg.gamma,
            gae_lambda=args["gae_lambda"],
            clip_range=args.get("clip_range"),
            ent_coef=args["ent_coef"],
            vf_coef=args["vf_coef"],
            max_grad_norm=args["max_grad_norm"],
            normalize_advantage=args["normalize_advantage"],
            sequence_length=seq,
        )


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
    optimizer: th.optim.Optimizer,
    s: OnPolicySettings,
    policy_loss: th.Tensor,
    value_loss: th.Tensor,
    entropy_loss: th.Tensor,
    k: int | None = None,
    means: AgentMeans | None = None,
) -> None:
    """One gradient step on the K agents' losses ``(K,)``: SB3's weighting, per-agent clipping
    (``k``: as :func:`~nutribench.engine.stacked.clip_grad_norm_per_agent`); the losses and
    the gradient norms go to ``means``."""
    loss = policy_loss + s.ent_coef * entropy_loss + s.vf_coef * value_loss
    optimizer.zero_grad()
    loss.sum().backward()  # disjoint parameters: each agent gets its own loss's gradient
    norms = clip_grad_norm_per_agent(params, s.max_grad_norm, k)
    optimizer.step()
    if means is not None:
        means.add(
            **{
                names.POLICY_LOSS: policy_loss,
                names.VALUE_LOSS: value_loss,
                names.ENTROPY_LOSS: entropy_loss,
                names.GRAD_NORM: norms,
            }
        )


def make_optimizer(net: Any, learning_rate: float) -> th.optim.Adam:
    """The on-policy agents' Adam (SB3's actor-critic policies: eps 1e-5) over ``net.params``."""
    return make_adam(net.params, learning_rate, ADAM_EPS)


class OnPolicyAlgorithm(Algorithm):
    """SB3's on-policy loop for the K agents of ``envs`` (the module docstring); subclasses
    give the network, the acting and the update."""

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device):
        super().__init__(cfg, envs, device)
        self.settings = OnPolicySettings.from_config(cfg, envs.horizon)
        generators = [th.Generator().manual_seed(int(r.integers(2**62))) for r in envs.rng["init"]]
        self.net = self.make_network(generators)
        self.actor = self.make_actor(self.net)
        self.optimizer = make_optimizer(self.net, self.settings.learning_rate)
        self.ret_stats = RunningStats(self.k) if cfg.normalize_reward else None
        self.discounted = np.zeros(self.k)
        self.means = AgentMeans()

    # ---- what each algorithm gives ----

    def make_network(self, generators: list[th.Generator]) -> Any:
        """The K agents' stacked network (``params``, ``store_sb3``), initialised from ``generators``."""
        raise NotImplementedError

    def make_actor(self, net: Any) -> Any:
        """Acting with ``net``: ``(obs (K, d), starts (K,), advance=True)`` -> logits, values."""
        raise NotImplementedError

    def units(self, steps: int) -> int:
        """How many items an epoch's permutation orders in a rollout of ``steps`` steps: its transitions."""
        return steps

    def update(self, rollout: Rollout, permutations: np.ndarray) -> None:
        """The algorithm's update of the K agents on ``rollout``, its losses into :attr:`means`."""
        raise NotImplementedError

    # ---- the loop ----

    @property
    def return_stats(self) -> RunningStats | None:
        return self.ret_stats

    def store_weights(self, j: int, model: Any) -> None:
        self.net.store_sb3(j, model.policy)

    def learn(self, total_steps: int, checkpoint: Checkpoint | None = None) -> float:
        envs, k, s, device = self.envs, self.k, self.settings, self.device
        obs_dim = envs.obs_dim
        n_rollouts = total_steps // s.n_steps
        saved = checkpoint.read_onto(device) if checkpoint is not None else None
        if saved is not None:
            envs.restore(saved["envs"])
            self.net, self.actor, self.optimizer, self.ret_stats, self.discounted = saved["model"]
            self.diagnostics = [list(rows) for rows in saved["diagnostics"]]
            obs, start_of_day, step, first = saved["obs"], saved["start_of_day"], saved["steps"], saved["rollout"]
        else:
            obs = envs.seen(envs.new_days())
            start_of_day = np.ones(k, dtype=np.float32)
            step = first = 0
        rng = envs.rng
        t0 = time.perf_counter()
        for rollout_index in range(first, n_rollouts + 1):
            if checkpoint is not None and rollout_index > first and checkpoint.due():
                checkpoint.save(
                    rollout=rollout_index,
                    steps=step,
                    envs=envs,
                    obs=obs,
                    start_of_day=start_of_day,
                    model=(self.net, self.actor, self.optimizer, self.ret_stats, self.discounted),
                    diagnostics=self.diagnostics,
                )
            T = s.n_steps if rollout_index < n_rollouts else total_steps - step
            if T == 0:
                break
            buf_obs = np.empty((k, T, obs_dim), dtype=np.float32)
            buf_act = np.empty((k, T), dtype=np.int64)
            buf_logp = np.empty((k, T), dtype=np.float32)
            buf_val = np.empty((k, T), dtype=np.float32)
            buf_rew = np.empty((k, T), dtype=np.float32)
            buf_start = np.empty((k, T), dtype=np.float32)
            uniforms = np.stack([r.random(T) for r in rng["actions"]])
            for t in range(T):
                self.day_boundary(step)
                with th.no_grad():
                    logits, values = self.actor(
                        th.as_tensor(obs, device=device), th.as_tensor(start_of_day, device=device)
                    )
                logp = th.log_softmax(logits, dim=-1).cpu().numpy()
                p_eat = np.exp(logp[:, 1])
                actions = (uniforms[:, t] < p_eat).astype(np.int64)
                buf_obs[:, t], buf_act[:, t], buf_start[:, t] = obs, actions, start_of_day
                buf_logp[:, t] = logp[np.arange(k), actions]
                buf_val[:, t] = values.cpu().numpy()
                raw_next, rewards, day_over = envs.step(actions, entropy=-(np.exp(logp) * logp).sum(axis=1))
                if self.ret_stats is not None:
                    self.discounted = self.discounted * s.gamma + rewards
                    self.ret_stats.update(self.discounted)
                    scaled = np.clip(rewards / np.sqrt(self.ret_stats.var + NORM_EPS), -CLIP_OBS, CLIP_OBS)
                else:
                    scaled = rewards
                buf_rew[:, t] = scaled
                step += 1
                if day_over:
                    self.discounted[:] = 0.0
                    raw_next = envs.new_days()
                    start_of_day = np.ones(k, dtype=np.float32)
                else:
                    start_of_day = np.zeros(k, dtype=np.float32)
                obs = envs.seen(raw_next)
            if T < s.n_steps:
                break  # a partial rollout: SB3 stops without updating on it
            with th.no_grad():
                _, last_values = self.actor(
                    th.as_tensor(obs, device=device), th.as_tensor(start_of_day, device=device), advance=False
                )
            adv, ret = gae(
                buf_rew,
                buf_val,
                buf_start,
                last_values.cpu().numpy(),
                start_of_day.astype(bool),
                s.gamma,
                s.gae_lambda,
            )
            if self.on_rollout is not None:
                self.on_rollout(
                    {
                        "obs": buf_obs,
                        "actions": buf_act,
                        "rewards": buf_rew,
                        "starts": buf_start,
                        "values": buf_val,
                        "advantages": adv,
                        "returns": ret,
                        "foods": np.stack(envs.days_drawn),
                    }
                )
            on = lambda x: th.as_tensor(x, device=device)  # noqa: E731
            rollout = Rollout(
                obs=on(buf_obs),
                actions=on(buf_act),
                log_probs=on(buf_logp),
                values=on(buf_val),
                advantages=on(adv),
                returns=on(ret),
            )
            units = self.units(T)
            perms = np.stack([[r.permutation(units) for r in rng["minibatches"]] for _ in range(s.n_epochs)])
            self.update(rollout, perms)
            self._record(step, buf_val, ret)
        return time.perf_counter() - t0 + (checkpoint.seconds_before if saved is not None else 0.0)

    def _record(self, step: int, values: np.ndarray, returns: np.ndarray) -> None:
        """The diagnostics of the update just made (one read of the device's sums)."""
        row: dict[str, Any] = {
            **self.means.means(),
            names.EXPLAINED_VARIANCE: explained_variance(values, returns),
            names.LEARNING_RATE: self.settings.learning_rate,
        }
        if self.ret_stats is not None:
            row[names.RETURN_SCALE] = np.sqrt(self.ret_stats.var + NORM_EPS)
        self.record(step, row)
