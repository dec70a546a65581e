"""Double DQN for K agents at once: SB3's ``DQN.learn`` with nutribench's double-DQN target
(:class:`~nutribench.agents.algos.DoubleDQN`), every agent's parameters stacked along a
leading agent axis.

Per agent, everything is what ``algos.build_model`` builds from ``ddqn.toml``:

* Q-network ``obs -> 256 -> 128 -> 2`` (ReLU), PyTorch's default ``Linear`` initialisation
  (SB3's ``QNetwork``), a target network copied from it; Adam (eps 1e-8) whose learning rate
  falls linearly from ``learning_rate_start`` to ``learning_rate_end`` over the budget;
* ``VecNormalize`` of the observations (each agent its own running statistics); the replay
  stores raw observations and raw rewards and normalises observations when sampling, with
  the statistics of that moment (SB3's off-policy habit);
* actions: uniformly random for the first ``learning_starts`` steps, then epsilon-greedy with
  epsilon falling linearly from ``exploration_initial_eps`` to ``exploration_final_eps`` over
  the first ``exploration_fraction`` of the budget;
* every ``train_freq`` steps after ``learning_starts``, ``gradient_steps`` updates on
  ``batch_size`` transitions drawn uniformly from the agent's own replay, with SB3's n-step
  returns (``NStepReplayBuffer``: rewards summed until the day's end or the newest
  transition, the target discounted by gamma to the number of steps summed); Huber loss; the
  gradient clipped to ``max_grad_norm`` per agent;
* a hard copy to the target network every ``target_update_interval`` steps.

The last step of the budget ends the job before its update, as the episode callback stops
SB3 there. Randomness is per agent, from its job seed (as in :mod:`nutribench.engine.train`).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th
from torch.nn import functional as F

from nutribench.agents.api import TrainedAgent
from nutribench.config import EnvConfig
from nutribench.engine.actor_critic import clip_grad_norm_per_agent
from nutribench.engine.envs import AgentEnvs, AgentEpisodeFn, as_trained_agent

ADAM_EPS = 1e-8  # SB3's DQNPolicy: Adam with torch's defaults


def linear_schedule(start: float, end: float, fraction: float, progress_remaining: float) -> float:
    """SB3's ``LinearSchedule``: ``start`` to ``end`` over the first ``fraction`` of training."""
    done = 1.0 - progress_remaining
    return end if done > fraction else start + done * (end - start) / fraction


class StackedMLP:
    """K copies of an MLP ``obs -> net_arch -> n_out`` (ReLU): layers ``(W (K, in, out),
    b (K, 1, out))``, each agent initialised as ``torch.nn.Linear`` is, from its own generator."""

    def __init__(self, k: int, sizes: list[int], generators: list[th.Generator] | None = None):
        self.params: list[th.Tensor] = []
        for n_in, n_out in zip(sizes[:-1], sizes[1:]):
            w, b = th.empty(k, n_in, n_out), th.empty(k, 1, n_out)
            bound = 1.0 / math.sqrt(n_in)
            for j in range(k):
                g = None if generators is None else generators[j]
                block = th.empty(n_out, n_in)
                th.nn.init.kaiming_uniform_(block, a=math.sqrt(5), generator=g)
                w[j] = block.T
                th.nn.init.uniform_(b[j], -bound, bound, generator=g)
            self.params += [w.requires_grad_(), b.requires_grad_()]

    def forward(self, x: th.Tensor) -> th.Tensor:
        """``x (K, B, in)`` -> ``(K, B, out)``."""
        p = self.params
        n = len(p) // 2
        for i in range(n):
            x = th.baddbmm(p[2 * i + 1], x, p[2 * i])
            if i < n - 1:
                x = th.relu(x)
        return x

    def copy_from(self, other: StackedMLP) -> None:
        with th.no_grad():
            for mine, theirs in zip(self.params, other.params):
                mine.copy_(theirs)

    def load_linears(self, j: int, linears: list[th.nn.Linear]) -> None:
        """Agent ``j``'s weights from a list of ``nn.Linear`` (e.g. an SB3 ``QNetwork``'s)."""
        with th.no_grad():
            for i, lin in enumerate(linears):
                self.params[2 * i][j].copy_(lin.weight.T)
                self.params[2 * i + 1][j, 0].copy_(lin.bias)

    def store_linears(self, j: int, linears: list[th.nn.Linear]) -> None:
        """Agent ``j``'s weights into a list of ``nn.Linear`` of the same shapes."""
        with th.no_grad():
            for i, lin in enumerate(linears):
                lin.weight.copy_(self.params[2 * i][j].T)
                lin.bias.copy_(self.params[2 * i + 1][j, 0])


def q_linears(q_net: th.nn.Module) -> list[th.nn.Linear]:
    """The ``Linear`` layers of an SB3 ``QNetwork``, input to output."""
    return [m for m in q_net.q_net if isinstance(m, th.nn.Linear)]


@dataclass
class Batch:
    """Sampled transitions of K agents, ``B`` each, as SB3's ``ReplayBufferSamples``."""

    obs: th.Tensor  # (K, B, obs_dim), normalised
    actions: th.Tensor  # (K, B) long
    rewards: th.Tensor  # (K, B) n-step discounted sums
    next_obs: th.Tensor  # (K, B, obs_dim), normalised, at the n-step transition's end
    dones: th.Tensor  # (K, B) 1 where the day ended within the n steps
    discounts: th.Tensor  # (K, B) gamma ** steps summed


class StackedReplay:
    """One replay per agent (raw observations and rewards), filled in step together; SB3's
    ``NStepReplayBuffer`` sampling for given indices."""

    def __init__(self, k: int, size: int, obs_dim: int, n_step: int, gamma: float):
        self.size, self.n_step, self.gamma = size, n_step, gamma
        # zeros, not empty: the n-step window reads (masked) entries past the newest one
        self.obs = np.zeros((k, size, obs_dim), dtype=np.float32)
        self.next_obs = np.zeros((k, size, obs_dim), dtype=np.float32)
        self.actions = np.zeros((k, size), dtype=np.int64)
        self.rewards = np.zeros((k, size), dtype=np.float32)
        self.dones = np.zeros((k, size), dtype=bool)
        self.pos, self.full = 0, False

    def add(self, obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray, next_obs: np.ndarray, dones: np.ndarray) -> None:
        p = self.pos
        self.obs[:, p], self.actions[:, p], self.rewards[:, p] = obs, actions, rewards
        self.next_obs[:, p], self.dones[:, p] = next_obs, dones
        self.pos = (p + 1) % self.size
        self.full = self.full or self.pos == 0

    @property
    def filled(self) -> int:
        return self.size if self.full else self.pos

    def sample(self, idx: np.ndarray, normalize) -> Batch:
        """The transitions at ``idx (K, B)``: n-step sums cut at a day's end or at the newest
        transition (which then bootstraps), observations through ``normalize``."""
        k = idx.shape[0]
        rows = np.arange(k)[:, None, None]
        window = (idx[:, :, None] + np.arange(self.n_step)) % self.size  # (K, B, n)
        newest = (self.pos - 1) % self.size
        dones = self.dones[rows, window]
        cut = dones | (window == newest)
        last = np.where(cut.any(axis=2), cut.argmax(axis=2), self.n_step - 1)  # (K, B)
        mask = np.arange(self.n_step) <= last[..., None]
        steps = mask.sum(axis=2)
        powers = self.gamma ** np.arange(self.n_step, dtype=np.float32)
        returns = (self.rewards[rows, window] * powers * mask).sum(axis=2)
        end = (idx + last) % self.size
        r2 = np.arange(k)[:, None]
        return Batch(
            obs=th.as_tensor(normalize(self.obs[r2, idx])), actions=th.as_tensor(self.actions[r2, idx]),
            rewards=th.as_tensor(returns.astype(np.float32)), next_obs=th.as_tensor(normalize(self.next_obs[r2, end])),
            dones=th.as_tensor(self.dones[r2, end].astype(np.float32)),
            discounts=th.as_tensor((self.gamma ** steps).astype(np.float32)),
        )  # fmt: skip


def ddqn_update(q: StackedMLP, q_target: StackedMLP, optimizer: th.optim.Optimizer, batch: Batch, learning_rate: float,
                max_grad_norm: float) -> np.ndarray:  # fmt: skip
    """One gradient step of :meth:`DoubleDQN.train` for the K agents; their Huber losses ``(K,)``."""
    for group in optimizer.param_groups:
        group["lr"] = learning_rate
    with th.no_grad():
        best = q.forward(batch.next_obs).argmax(dim=2, keepdim=True)
        next_q = th.gather(q_target.forward(batch.next_obs), 2, best).squeeze(2)
        target = batch.rewards + (1 - batch.dones) * batch.discounts * next_q
    current = th.gather(q.forward(batch.obs), 2, batch.actions.unsqueeze(2)).squeeze(2)
    loss = F.smooth_l1_loss(current, target, reduction="none").mean(dim=1)
    optimizer.zero_grad()
    loss.sum().backward()
    clip_grad_norm_per_agent(q.params, max_grad_norm)
    optimizer.step()
    return loss.detach().numpy()


def make_q_optimizer(q: StackedMLP, learning_rate: float) -> th.optim.Adam:
    """Adam over the stacked Q-network (fused where torch has it on the CPU)."""
    try:
        return th.optim.Adam(q.params, lr=learning_rate, eps=ADAM_EPS, fused=True)
    except RuntimeError:  # pragma: no cover - torch < 2.4 on CPU
        return th.optim.Adam(q.params, lr=learning_rate, eps=ADAM_EPS, foreach=True)


def train_ddqn_batched(jobs: Sequence[tuple[str | EnvConfig, int]], cfg: Any, episodes: int,
                       on_episode: AgentEpisodeFn | None = None,
                       on_update: Callable[[dict[str, Any]], None] | None = None) -> list[TrainedAgent]:  # fmt: skip
    """Train one DDQN agent of ``cfg`` per ``(regime, seed)`` of ``jobs`` for ``episodes`` days, all at once.

    :param on_update: called after each update with ``steps`` (env steps so far), the
        ``learning_rate`` and ``epsilon`` in force, ``target_copies`` so far and the K ``losses``.
    """
    envs = AgentEnvs(jobs, cfg.normalize_obs, on_episode)
    k, rng = envs.k, envs.rng
    sizes = [envs.obs_dim, *cfg.net_arch, 2]
    q = StackedMLP(k, sizes, generators=[th.Generator().manual_seed(int(r.integers(2**62))) for r in rng["init"]])
    q_target = StackedMLP(k, sizes)
    q_target.copy_from(q)
    optimizer = make_q_optimizer(q, cfg.learning_rate_start)
    total = episodes * envs.horizon
    replay = StackedReplay(k, min(cfg.buffer_size, total), envs.obs_dim, cfg.n_step, cfg.gamma)
    raw = envs.new_days()
    obs = envs.seen(raw)
    copies = 0
    epsilon = 0.0  # SB3's DQN until its first step's schedule update (read only if learning_starts = 0)
    t0 = time.perf_counter()
    for n in range(total):  # n env steps taken so far
        t = n % envs.horizon
        if t == 0:  # each agent's random actions and epsilon coins for the day, from its own stream
            random_actions = np.stack([r.integers(0, 2, size=envs.horizon) for r in rng["actions"]])
            coins = np.stack([r.random(envs.horizon) for r in rng["actions"]])
        if n < cfg.learning_starts:
            actions = random_actions[:, t]
        else:
            with th.no_grad():
                greedy = q.forward(th.as_tensor(obs).unsqueeze(1))[:, 0].argmax(dim=1).numpy()
            actions = np.where(coins[:, t] < epsilon, random_actions[:, t], greedy)
        raw_next, rewards, day_over = envs.step(actions)
        replay.add(raw, actions, rewards, raw_next, np.full(k, day_over))
        steps = n + 1
        progress = 1.0 - steps / total
        if steps % cfg.target_update_interval == 0:
            q_target.copy_from(q)
            copies += 1
        epsilon = linear_schedule(cfg.exploration_initial_eps, cfg.exploration_final_eps, cfg.exploration_fraction, progress)
        raw = envs.new_days() if day_over else raw_next
        obs = envs.seen(raw)
        if steps % cfg.train_freq == 0 and steps > cfg.learning_starts and steps < total:
            lr = linear_schedule(cfg.learning_rate_start, cfg.learning_rate_end, 1.0, progress)
            for _ in range(cfg.gradient_steps):
                idx = np.stack([r.integers(0, replay.filled, size=cfg.batch_size) for r in rng["minibatches"]])
                losses = ddqn_update(q, q_target, optimizer, replay.sample(idx, envs.normalize), lr, cfg.max_grad_norm)
                if on_update is not None:
                    on_update({"steps": steps, "learning_rate": lr, "epsilon": epsilon, "target_copies": copies, "losses": losses})
    wall = time.perf_counter() - t0
    return [as_trained_agent(envs, j, cfg, episodes, lambda model, j=j: _store(q, q_target, j, model), None, wall / k)
            for j in range(k)]  # fmt: skip


def _store(q: StackedMLP, q_target: StackedMLP, j: int, model: Any) -> None:
    q.store_linears(j, q_linears(model.q_net))
    q_target.store_linears(j, q_linears(model.q_net_target))
