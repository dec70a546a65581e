"""What the batched engine's off-policy algorithms (DDQN, discrete SAC) share: one replay
per agent with SB3's sampling, SB3's linear schedule, and SB3's ``OffPolicyAlgorithm.learn``
loop for K agents stepped together (:class:`OffPolicyAlgorithm`).

The loop, per agent as SB3 runs it with one env: act (the algorithm decides: uniformly
random during ``learning_starts``), step, store the raw transition (SB3 stores raw
observations and rewards and normalises observations when sampling, with the statistics of
that moment), then every ``train_freq`` steps after ``learning_starts``,
``gradient_steps`` updates on ``batch_size`` transitions drawn uniformly from the agent's
own replay. The last step of the budget ends the job before its update, as the episode
callback stops SB3 there.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from nutribench.engine.algorithm import Algorithm
from nutribench.engine.checkpoint import Checkpoint, register
from nutribench.engine.envs import AgentEnvs
from nutribench.engine.stacked import AgentMeans


def linear_schedule(start: float, end: float, fraction: float, progress_remaining: float) -> float:
    """SB3's ``LinearSchedule``: ``start`` to ``end`` over the first ``fraction`` of training."""
    done = 1.0 - progress_remaining
    return end if done > fraction else start + done * (end - start) / fraction


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


register(StackedReplay)  # what its checkpoints hold


#: Adam's eps in SB3's off-policy policies (DQN, and DiscreteSAC's): torch's default.
OFF_POLICY_ADAM_EPS = 1e-8


class OffPolicyAlgorithm(Algorithm):
    """SB3's off-policy loop for the K agents of ``envs`` (the module docstring); subclasses
    give the acting (:meth:`act`), the update (:meth:`update`), what happens after each env
    step (:meth:`after_step`), the replay's n-step (:attr:`n_step`) and what a checkpoint
    keeps of them (:meth:`model_state`, :meth:`restore_model`). Their updates add their
    quantities to :attr:`means`; each day with updates gives every agent one diagnostics
    dict of that day's means."""

    #: the replay's n-step returns (SB3's ``NStepReplayBuffer``; 1: one-step transitions)
    n_step = 1

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device):
        super().__init__(cfg, envs, device)
        self.means = AgentMeans()

    def act(
        self, obs: np.ndarray, n: int, uniforms: np.ndarray, random_actions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The K actions at normalised ``obs`` after ``n`` env steps, given each agent's uniform
        draw and random action for this step; and the policy's entropy per agent (None for a
        policy without one)."""
        raise NotImplementedError

    def after_step(self, steps: int, progress_remaining: float) -> None:
        """After each env step (SB3's ``_on_step``): nothing unless the algorithm says."""

    def update(self, steps: int, progress_remaining: float, batch: Batch) -> None:
        """One gradient step of the K agents on ``batch``."""
        raise NotImplementedError

    def model_state(self) -> Any:
        """Everything :meth:`act` and :meth:`update` change (networks, optimisers, counters), for a checkpoint."""
        raise NotImplementedError

    def restore_model(self, state: Any) -> None:
        """Take over :meth:`model_state` read from a checkpoint."""
        raise NotImplementedError

    def learn(self, total_steps: int, checkpoint: Checkpoint | None = None) -> float:
        """Run ``total_steps`` env steps of SB3's off-policy loop; reads ``buffer_size``,
        ``learning_starts``, ``train_freq``, ``gradient_steps``, ``batch_size`` and ``gamma``
        from the config. With a ``checkpoint``, resumes from its state if it has one, and
        saves itself and :meth:`model_state` at day boundaries when it is due. Sampled
        batches go to the device."""
        envs, cfg, total = self.envs, self.cfg, total_steps
        saved = checkpoint.read_onto(self.device) if checkpoint is not None else None
        if saved is not None:
            envs.restore(saved["envs"])
            self.restore_model(saved["model"])
            self.diagnostics = [list(rows) for rows in saved["diagnostics"]]
            replay, raw, obs, start = saved["replay"], saved["raw"], saved["obs"], saved["steps"]
        else:
            replay = StackedReplay(envs.k, min(cfg.buffer_size, total), envs.obs_dim, self.n_step, cfg.gamma)
            raw = envs.new_days()
            obs, start = envs.seen(raw), 0
        rng = envs.rng
        t0 = time.perf_counter()
        for n in range(start, total):  # n env steps taken so far
            t = n % envs.horizon
            self.day_boundary(n)
            if t == 0 and checkpoint is not None and n > start and checkpoint.due():
                checkpoint.save(
                    steps=n,
                    envs=envs,
                    replay=replay,
                    raw=raw,
                    obs=obs,
                    model=self.model_state(),
                    diagnostics=self.diagnostics,
                )
            if t == 0:  # each agent's random actions and uniform draws for the day, from its own stream
                random_actions = np.stack([r.integers(0, 2, size=envs.horizon) for r in rng["actions"]])
                uniforms = np.stack([r.random(envs.horizon) for r in rng["actions"]])
            actions, entropy = self.act(obs, n, uniforms[:, t], random_actions[:, t])
            raw_next, rewards, day_over = envs.step(actions, entropy)
            replay.add(raw, actions, rewards, raw_next, np.full(envs.k, day_over))
            steps = n + 1
            progress = 1.0 - steps / total
            self.after_step(steps, progress)
            raw = envs.new_days() if day_over else raw_next
            obs = envs.seen(raw)
            if steps % cfg.train_freq == 0 and steps > cfg.learning_starts and steps < total:
                for _ in range(cfg.gradient_steps):
                    idx = np.stack([r.integers(0, replay.filled, size=cfg.batch_size) for r in rng["minibatches"]])
                    self.update(steps, progress, replay.sample(idx, envs.normalize, self.device))
            if day_over and self.means:
                self.record(steps, self.means.means())  # the day's means, one read
        return time.perf_counter() - t0 + (checkpoint.seconds_before if saved is not None else 0.0)
