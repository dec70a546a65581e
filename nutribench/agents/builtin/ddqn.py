"""DDQN: SB3's ``DQN`` whose target is the double-DQN one (the online net picks
``argmax_a Q(s', a)``, the target net values it), with SB3's n-step replay, a linear
learning-rate schedule and hard target copies. Plain SB3's ``DQN`` loads and acts with its
models."""

from __future__ import annotations

import warnings
from typing import Any, Literal

import numpy as np
import torch as th
from pydantic import model_validator
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.buffers import NStepReplayBuffer
from stable_baselines3.common.utils import LinearSchedule
from torch.nn import functional as F

from nutribench.agents.config import FeedForward, GradNorm, NonNegInt, PosFloat, PosInt, Prob, Transitions
from nutribench.agents.registry import Algorithm, no_replay_scaling
from nutribench.config.sizes import n_step_bytes, too_large


class DDQNConfig(FeedForward):
    """Double DQN with n-step returns."""

    algo: Literal["ddqn"]
    learning_rate_start: PosFloat
    learning_rate_end: PosFloat
    buffer_size: Transitions
    learning_starts: NonNegInt
    batch_size: Transitions
    n_step: PosInt
    max_grad_norm: GradNorm
    target_update_interval: PosInt
    train_freq: PosInt
    gradient_steps: PosInt
    exploration_initial_eps: Prob
    exploration_final_eps: Prob
    exploration_fraction: Prob

    @model_validator(mode="after")
    def _n_step_returns_that_fit(self) -> DDQNConfig:
        """Refuse n-step returns whose batch could never be gathered (:func:`nutribench.config.sizes.n_step_bytes`)."""
        why = too_large(
            f"batch_size = {self.batch_size:,} with n_step = {self.n_step:,}: a batch's n-step returns",
            n_step_bytes(self.batch_size, self.n_step),
        )
        if why:
            raise ValueError(why)
        return self


def double_dqn_target(
    q_online_next: th.Tensor,
    q_target_next: th.Tensor,
    rewards: th.Tensor,
    dones: th.Tensor,
    discounts: th.Tensor | float,
) -> th.Tensor:
    """``r + discount * (1 - done) * Q_target(s', argmax_a Q_online(s', a))``, shape ``(batch, 1)``.

    :param q_online_next: ``(batch, n_actions)`` online network at the next states.
    :param q_target_next: ``(batch, n_actions)`` target network at the next states.
    :param rewards: ``(batch, 1)`` (n-step discounted) rewards.
    :param dones: ``(batch, 1)`` episode ended within the n steps.
    :param discounts: ``gamma ** n`` per sample ``(batch, 1)`` or a float.
    """
    best = q_online_next.argmax(dim=1, keepdim=True)
    next_q = th.gather(q_target_next, dim=1, index=best)
    return rewards + (1 - dones) * discounts * next_q


class DoubleDQN(DQN):
    """SB3 DQN with the double-DQN target; everything else (n-step replay, epsilon-greedy,
    hard target copies, Huber loss, gradient clipping) is SB3's. Each update also logs
    ``train/q_mean`` (mean Q of the batch's actions) and ``train/grad_norm`` (before clipping)."""

    def _excluded_save_params(self) -> list[str]:
        """Also the replay buffer's class: SB3 chose it from ``n_steps`` (its n-step buffer) and
        chooses it again on load. Saved, it made every plain ``DQN.load`` warn that
        ``n_steps=5`` "is ignored because a custom replay_buffer_class was passed", which is
        not so: the saved ``replay_buffer_kwargs`` carry ``n_steps`` and ``gamma``, and the
        loaded model's buffer is the n-step one."""
        return [*super()._excluded_save_params(), "replay_buffer_class"]

    def _setup_model(self) -> None:
        """SB3's, with that warning silenced where it is false (a file saved before the class
        was left out: its buffer class and kwargs both say n-step, so n-step returns are set up)."""
        kwargs = self.replay_buffer_kwargs or {}
        if self.replay_buffer_class is NStepReplayBuffer and kwargs.get("n_steps") == self.n_steps:
            with warnings.catch_warnings():
                warnings.filterwarnings(
                    "ignore", message=r"`n_steps=\d+` is ignored because a custom", category=UserWarning
                )
                super()._setup_model()
        else:
            super()._setup_model()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses, grad_norms, q_means = [], [], []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            discounts = data.discounts if data.discounts is not None else self.gamma
            with th.no_grad():
                target = double_dqn_target(
                    self.q_net(data.next_observations),
                    self.q_net_target(data.next_observations),
                    data.rewards,
                    data.dones,
                    discounts,
                )
            current = th.gather(self.q_net(data.observations), dim=1, index=data.actions.long())
            loss = F.smooth_l1_loss(current, target)
            losses.append(loss.item())
            q_means.append(current.detach().mean().item())
            self.policy.optimizer.zero_grad()
            loss.backward()
            grad_norms.append(th.nn.utils.clip_grad_norm_(self.policy.parameters(), self.max_grad_norm).item())
            self.policy.optimizer.step()
        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        self.logger.record("train/loss", float(np.mean(losses)))
        self.logger.record("train/q_mean", float(np.mean(q_means)))
        self.logger.record("train/grad_norm", float(np.mean(grad_norms)))

    def day_entropy(self, obs: np.ndarray) -> None:
        """Epsilon-greedy over Q-values: no stochastic policy whose entropy to record."""
        return None


def ddqn_arguments(cfg: DDQNConfig, horizon: int) -> tuple[type[BaseAlgorithm], dict[str, Any]]:
    """Double DQN: a linear learning-rate schedule, hard target copies (tau 1)."""
    return DoubleDQN, dict(
        policy="MlpPolicy",
        learning_rate=LinearSchedule(cfg.learning_rate_start, cfg.learning_rate_end, end_fraction=1.0),
        buffer_size=cfg.buffer_size,
        learning_starts=cfg.learning_starts,
        batch_size=cfg.batch_size,
        n_steps=cfg.n_step,
        max_grad_norm=cfg.max_grad_norm,
        target_update_interval=cfg.target_update_interval,
        train_freq=cfg.train_freq,
        gradient_steps=cfg.gradient_steps,
        exploration_initial_eps=cfg.exploration_initial_eps,
        exploration_final_eps=cfg.exploration_final_eps,
        exploration_fraction=cfg.exploration_fraction,
        tau=1.0,
        policy_kwargs=dict(net_arch=list(cfg.net_arch)),
    )


ALGORITHM = Algorithm(
    "ddqn",
    DDQNConfig,
    arguments=f"{__name__}:ddqn_arguments",
    load=f"{__name__}:DoubleDQN",
    plain="stable_baselines3.DQN",
    label="DDQN",
    color="#1f77b4",
    order=2,
    batched="nutribench.engine.ddqn:BatchedDDQN",
    batch_limits=no_replay_scaling,
    bench_days=2000,  # the epsilon schedule and 10k-step warm-up: slower by design
    bare=(
        (f"{__name__}:DoubleDQN", "bare SB3 DQN loop, double target"),
        ("stable_baselines3:DQN", "bare SB3 DQN, vanilla target"),
    ),
)
