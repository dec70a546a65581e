"""What the batched engine's off-policy algorithms (DDQN, discrete SAC) share: one replay
per agent with SB3's sampling, and SB3's ``OffPolicyAlgorithm.learn``
loop for K agents stepped together (:class:`BatchedOffPolicyAlgorithm`).

The loop, per agent as SB3 runs it with one env: act (the algorithm decides: uniformly
random during ``learning_starts``), step, store the raw transition (SB3 stores raw
observations and rewards and normalises observations when sampling, with the statistics of
that moment), then every ``train_freq`` steps after ``learning_starts``,
``gradient_steps`` updates on ``batch_size`` transitions drawn uniformly from the agent's
own replay. The last step of the budget ends the job before its update, as the episode
callback stops SB3 there.

As SB3's, the loop is three methods: :meth:`~BatchedOffPolicyAlgorithm.learn` (resume from a
checkpoint, then steps until the budget, saving :meth:`~BatchedOffPolicyAlgorithm.state_dict` at
day boundaries when due), :meth:`~BatchedOffPolicyAlgorithm.collect_rollouts` (one env step of every
agent into its replay; it tells whether the day ended) and :meth:`~BatchedOffPolicyAlgorithm.train`
(``gradient_steps`` updates on sampled batches). Each day's end (a day boundary: every
agent's day ends at once) closes that day's diagnostics row.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch as th

from nutribench.engine.algorithm import BatchedAlgorithm
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.envs import AgentEnvs


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

    #: the arrays a checkpoint keeps (in :meth:`add`'s order), and their dtypes
    ARRAYS = {"obs": np.float32, "next_obs": np.float32, "actions": np.int64, "rewards": np.float32, "dones": bool}

    def __init__(self, k: int, size: int, obs_dim: int, n_step: int, gamma: float):
        self.size, self.n_step, self.gamma = size, n_step, gamma
        # zeros, not empty: the n-step window reads (masked) entries past the newest one
        for name, dtype in self.ARRAYS.items():
            setattr(self, name, np.zeros((k, size, obs_dim) if "obs" in name else (k, size), dtype=dtype))
        self.pos, self.full = 0, False

    def add(
        self, obs: np.ndarray, actions: np.ndarray, rewards: np.ndarray, next_obs: np.ndarray, dones: np.ndarray
    ) -> None:
        for name, value in zip(self.ARRAYS, (obs, next_obs, actions, rewards, dones)):
            getattr(self, name)[:, self.pos] = value
        self.pos = (self.pos + 1) % self.size
        self.full = self.full or self.pos == 0

    def state_dict(self) -> dict[str, Any]:
        arrays = {name: getattr(self, name) for name in self.ARRAYS}
        return {"arrays": arrays, **{name: getattr(self, name) for name in ("pos", "full", "n_step", "gamma")}}

    @classmethod
    def from_state_dict(cls, state: dict[str, Any]) -> StackedReplay:
        """The replay of ``state`` (:meth:`state_dict`)."""
        arrays = state["arrays"]
        k, size, obs_dim = arrays["obs"].shape
        replay = cls(k, size, obs_dim, int(state["n_step"]), float(state["gamma"]))
        for name in cls.ARRAYS:
            mine = getattr(replay, name)
            if arrays[name].shape != mine.shape or arrays[name].dtype != mine.dtype:
                raise ValueError("the checkpoint's replay does not fit this batch")
            setattr(replay, name, arrays[name])
        replay.pos, replay.full = int(state["pos"]), bool(state["full"])
        return replay

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


#: Adam's eps in SB3's off-policy policies (DQN, and DiscreteSAC's): torch's default.
OFF_POLICY_ADAM_EPS = 1e-8


class BatchedOffPolicyAlgorithm(BatchedAlgorithm):
    """SB3's off-policy loop for the K agents of ``envs`` (the module docstring); subclasses
    give the acting (:meth:`act`), the update (:meth:`update`), what happens after each env
    step (:meth:`after_step`), the replay's n-step (:attr:`n_step`) and what a checkpoint
    keeps of them (:meth:`model_state_dict`, :meth:`load_model_state_dict`: by default the
    stacked ``net``'s). Their updates add
    their quantities to :attr:`means`; each day with updates gives every agent one diagnostics
    dict of that day's means."""

    #: the replay's n-step returns (SB3's ``NStepReplayBuffer``; 1: one-step transitions)
    n_step = 1
    #: network forwards (a backward counted as 2) per replayed sample of an update
    FORWARDS_PER_SAMPLE = 1

    @classmethod
    def flops_per_env_step(cls, cfg: Any, obs_dim: int = 13, n_actions: int = 2, horizon: int = 50) -> float:
        """Matrix-product FLOPs per env step once learning has started: one forward to act, and
        per update (every ``train_freq`` steps, ``gradient_steps`` of them) ``batch_size``
        samples of :attr:`FORWARDS_PER_SAMPLE` forwards of the ``net_arch`` MLP."""
        sizes = [obs_dim, *cfg.net_arch, n_actions]
        forward = 2 * sum(a * b for a, b in zip(sizes[:-1], sizes[1:]))
        return forward * (1 + cls.FORWARDS_PER_SAMPLE * cfg.batch_size * cfg.gradient_steps / cfg.train_freq)

    def __init__(self, cfg: Any, envs: AgentEnvs, device: th.device, cfgs: list[Any] | None = None):
        super().__init__(cfg, envs, device, cfgs)
        self.replay: StackedReplay | None = None  # made when learning starts (its size depends on the budget)
        #: the raw observations the agents act on next (:attr:`last_obs` as the policies see them)
        self.raw: np.ndarray | None = None
        #: each agent's random actions and uniform draws for the day (drawn at its start)
        self.day_draws: tuple[np.ndarray, np.ndarray] | None = None

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

    def model_state_dict(self) -> dict[str, Any]:
        """Everything :meth:`act` and :meth:`update` change (networks' parameters, optimisers'
        ``state_dict``, counters), as plain data for a checkpoint (here: the stacked ``net``'s)."""
        return self.net.state_dict()  # type: ignore[attr-defined]

    def load_model_state_dict(self, state: dict[str, Any]) -> None:
        """Take over :meth:`model_state_dict` read from a checkpoint (in place)."""
        self.net.load_state_dict(state)  # type: ignore[attr-defined]

    def learn(self, total_steps: int, checkpoint: Checkpoint | None = None) -> float:
        """Run ``total_steps`` env steps of SB3's off-policy loop; reads ``buffer_size``,
        ``learning_starts``, ``train_freq``, ``gradient_steps``, ``batch_size`` and ``gamma``
        from the config. With a ``checkpoint``, resumes from its state if it has one, and
        saves :meth:`state_dict` at day boundaries when it is due. Sampled batches go to the device."""
        envs, cfg = self.envs, self.cfg
        seconds_before = self.resume(checkpoint)
        if self.replay is None:
            self.replay = StackedReplay(envs.k, min(cfg.buffer_size, total_steps), envs.obs_dim, self.n_step, cfg.gamma)
            self.raw = envs.new_days()
            self.last_obs = envs.seen(self.raw)
        first, t0 = self.num_timesteps, time.perf_counter()
        while self.num_timesteps < total_steps:
            self.day_boundary(self.num_timesteps)  # the evaluation during training that is due, if any
            start_of_day = self.num_timesteps % envs.horizon == 0
            if start_of_day and checkpoint is not None and self.num_timesteps > first and checkpoint.due():
                checkpoint.save(**self.state_dict())
            day_over = self.collect_rollouts(total_steps)
            steps = self.num_timesteps
            if steps % cfg.train_freq == 0 and steps > cfg.learning_starts and steps < total_steps:
                self.train(cfg.gradient_steps, 1.0 - steps / total_steps)
            if day_over and self.means:  # a day boundary: the day's means, one read
                self.record(steps, self.means.means())
        return time.perf_counter() - t0 + seconds_before

    def collect_rollouts(self, total_steps: int) -> bool:
        """One env step of every agent (of a budget of ``total_steps``), stored in its replay;
        whether it ended the day."""
        envs, n = self.envs, self.num_timesteps
        t = n % envs.horizon
        if t == 0:  # each agent's random actions and uniform draws for the day, from its own stream
            random_actions = np.stack([r.integers(0, 2, size=envs.horizon) for r in envs.rng["actions"]])
            self.day_draws = (random_actions, np.stack([r.random(envs.horizon) for r in envs.rng["actions"]]))
        random_actions, uniforms = self.day_draws
        actions, entropy = self.act(self.last_obs, n, uniforms[:, t], random_actions[:, t])
        raw_next, rewards, day_over = envs.step(actions, entropy)
        self.replay.add(self.raw, actions, rewards, raw_next, np.full(envs.k, day_over))
        self.num_timesteps = steps = n + 1
        self.after_step(steps, 1.0 - steps / total_steps)
        self.raw = envs.new_days() if day_over else raw_next
        self.last_obs = envs.seen(self.raw)
        return day_over

    def train(self, gradient_steps: int, progress_remaining: float) -> None:
        """``gradient_steps`` updates of the K agents, each on ``batch_size`` transitions drawn
        uniformly from each agent's replay with its own stream."""
        replay, batch_size = self.replay, self.cfg.batch_size
        for _ in range(gradient_steps):
            idx = np.stack([r.integers(0, replay.filled, size=batch_size) for r in self.envs.rng["minibatches"]])
            batch = replay.sample(idx, self.envs.normalize, self.device)
            self.update(self.num_timesteps, progress_remaining, batch)

    def state_dict(self) -> dict[str, Any]:
        return {
            **super().state_dict(),
            "replay": self.replay.state_dict(),
            "raw": self.raw,
            "obs": self.last_obs,
            "model": self.model_state_dict(),
        }

    def load_state_dict(self, state: dict[str, Any]) -> None:
        super().load_state_dict(state)
        if self.num_timesteps % self.envs.horizon:
            raise ValueError("the checkpoint was not saved at a day boundary")
        self.replay = StackedReplay.from_state_dict(state["replay"])
        self.raw, self.last_obs = np.asarray(state["raw"]), np.asarray(state["obs"], dtype=np.float32)
        self.load_model_state_dict(state["model"])
