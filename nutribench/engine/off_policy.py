"""What the batched engine's off-policy algorithms (DDQN, discrete SAC) share: stacked MLPs,
one replay per agent with SB3's sampling, SB3's linear schedule, and SB3's
``OffPolicyAlgorithm.learn`` loop for K agents stepped together.

The loop, per agent as SB3 runs it with one env: act (the algorithm decides: uniformly
random during ``learning_starts``), step, store the raw transition (SB3 stores raw
observations and rewards and normalises observations when sampling, with the statistics of
that moment), then every ``train_freq`` steps after ``learning_starts``,
``gradient_steps`` updates on ``batch_size`` transitions drawn uniformly from the agent's
own replay. The last step of the budget ends the job before its update, as the episode
callback stops SB3 there.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from nutribench.engine.actor_critic import RunningStats
from nutribench.engine.checkpoint import Checkpoint, register
from nutribench.engine.device import leaves_on
from nutribench.engine.envs import AgentEnvs


def linear_schedule(start: float, end: float, fraction: float, progress_remaining: float) -> float:
    """SB3's ``LinearSchedule``: ``start`` to ``end`` over the first ``fraction`` of training."""
    done = 1.0 - progress_remaining
    return end if done > fraction else start + done * (end - start) / fraction


class StackedMLP:
    """K copies of an MLP ``obs -> net_arch -> n_out`` (ReLU): layers ``(W (K, in, out),
    b (K, 1, out))``, each agent initialised as ``torch.nn.Linear`` is, from its own generator
    (None: torch's global one), on the CPU, then moved to ``device``."""

    def __init__(
        self,
        k: int,
        sizes: list[int],
        generators: list[th.Generator] | None = None,
        device: th.device | str | None = None,
    ):
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
        self.params = leaves_on(self.params, device)

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

    def add(
        self, obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray, next_obs: np.ndarray, dones: np.ndarray
    ) -> None:
        p = self.pos
        self.obs[:, p], self.actions[:, p], self.rewards[:, p] = obs, actions, rewards
        self.next_obs[:, p], self.dones[:, p] = next_obs, dones
        self.pos = (p + 1) % self.size
        self.full = self.full or self.pos == 0

    @property
    def filled(self) -> int:
        return self.size if self.full else self.pos

    def sample(self, idx: np.ndarray, normalize, device: th.device | str | None = None) -> Batch:
        """The transitions at ``idx (K, B)``: n-step sums cut at a day's end or at the newest
        transition (which then bootstraps), observations through ``normalize``; sampled on
        the CPU (numpy), the batch's tensors on ``device`` (None: the CPU)."""
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
        on = lambda x: th.as_tensor(x, device=device)  # noqa: E731
        return Batch(
            obs=on(normalize(self.obs[r2, idx])),
            actions=on(self.actions[r2, idx]),
            rewards=on(returns.astype(np.float32)),
            next_obs=on(normalize(self.next_obs[r2, end])),
            dones=on(self.dones[r2, end].astype(np.float32)),
            discounts=on((self.gamma**steps).astype(np.float32)),
        )


register(StackedMLP, StackedReplay, RunningStats)  # what its checkpoints hold


#: Adam's eps in SB3's off-policy policies (DQN, and DiscreteSAC's): torch's default.
OFF_POLICY_ADAM_EPS = 1e-8


#: ``act(obs, n, uniforms, random_actions)``: the K actions at normalised ``obs`` after ``n``
#: env steps, given each agent's uniform draw and random action for this step; and the
#: policy's entropy per agent (None for a policy without one).
ActFn = Callable[[np.ndarray, int, np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray | None]]


def run_off_policy(
    envs: AgentEnvs,
    cfg,
    total: int,
    act: ActFn,
    update: Callable[[int, float, Batch], None],
    after_step: Callable[[int, float], None] | None = None,
    n_step: int = 1,
    checkpoint: Checkpoint | None = None,
    model: Any = None,
    device: th.device | str | None = None,
) -> float:
    """Run ``total`` env steps of SB3's off-policy loop for the K agents of ``envs``; reads
    ``buffer_size``, ``learning_starts``, ``train_freq``, ``gradient_steps``,
    ``batch_size`` and ``gamma`` from ``cfg``. ``after_step(steps, progress_remaining)``
    runs after each step (SB3's ``_on_step``), ``update(steps, progress_remaining, batch)``
    ``gradient_steps`` times at each training point. With a ``checkpoint``, the loop
    resumes from its state if it has one, and saves itself and ``model`` (everything the
    caller's ``act``/``update`` change: networks, optimisers, counters) at day boundaries
    when it is due. Sampled batches go to ``device`` (None: the CPU). Returns the wall
    seconds (of the processes before a resume too)."""
    rng = envs.rng
    saved = checkpoint.state if checkpoint is not None else None
    if saved is not None:
        envs.restore(saved["envs"])
        rng, replay, raw, obs, start = envs.rng, saved["replay"], saved["raw"], saved["obs"], saved["steps"]
    else:
        replay = StackedReplay(envs.k, min(cfg.buffer_size, total), envs.obs_dim, n_step, cfg.gamma)
        raw = envs.new_days()
        obs, start = envs.seen(raw), 0
    t0 = time.perf_counter()
    for n in range(start, total):  # n env steps taken so far
        t = n % envs.horizon
        if t == 0 and checkpoint is not None and n > start and checkpoint.due():
            checkpoint.save(steps=n, envs=envs, replay=replay, raw=raw, obs=obs, model=model)
        if t == 0:  # each agent's random actions and uniform draws for the day, from its own stream
            random_actions = np.stack([r.integers(0, 2, size=envs.horizon) for r in rng["actions"]])
            uniforms = np.stack([r.random(envs.horizon) for r in rng["actions"]])
        actions, entropy = act(obs, n, uniforms[:, t], random_actions[:, t])
        raw_next, rewards, day_over = envs.step(actions, entropy)
        replay.add(raw, actions, rewards, raw_next, np.full(envs.k, day_over))
        steps = n + 1
        progress = 1.0 - steps / total
        if after_step is not None:
            after_step(steps, progress)
        raw = envs.new_days() if day_over else raw_next
        obs = envs.seen(raw)
        if steps % cfg.train_freq == 0 and steps > cfg.learning_starts and steps < total:
            for _ in range(cfg.gradient_steps):
                idx = np.stack([r.integers(0, replay.filled, size=cfg.batch_size) for r in rng["minibatches"]])
                update(steps, progress, replay.sample(idx, envs.normalize, device))
    return time.perf_counter() - t0 + (checkpoint.seconds_before if saved is not None else 0.0)
