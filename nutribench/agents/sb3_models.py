"""The built-in algorithms' own SB3 model classes where they are small: MC's
:class:`MonteCarloAC`, DDQN's :class:`DoubleDQN` (and its target, :func:`double_dqn_target`),
PPO's :class:`PPOWithGradNorm` (SAC's and GRU-PPO's are packages of their own,
:mod:`nutribench.agents.sac` and :mod:`nutribench.agents.gru_ppo`, whose policies share
:class:`FlatDiscretePolicy`).

They live apart from their algorithms' modules (:mod:`nutribench.agents.builtin`) so that
reading and checking an agent config imports neither torch nor Stable-Baselines3: a module of
the built-in package imports this one only when it builds a model, and still answers these
names (``nutribench.agents.builtin.ddqn.DoubleDQN``, the ``load`` of its registry entry) through
its ``__getattr__``. Their saved models name no class of this module: SB3's zip stores the
policy's class, and plain SB3's ``A2C``, ``DQN`` and ``PPO`` load them.
"""

from __future__ import annotations

import warnings
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.buffers import NStepReplayBuffer
from stable_baselines3.common.policies import BasePolicy
from torch.nn import functional as F


class FlatDiscretePolicy(BasePolicy):
    """What nutribench's own SB3 policies (GRU-PPO's and discrete SAC's) share: a flat ``Box``
    of observations and ``Discrete`` actions (:meth:`sizes` checks them), and the constructor
    parameters they keep under the same names, :attr:`KEPT`, saved with the model (its
    ``lr_schedule`` is not needed to load the policy alone)."""

    KEPT: ClassVar[tuple[str, ...]] = ()

    def sizes(self) -> tuple[int, int]:
        """The observation's and the action space's sizes; ValueError for other spaces."""
        name, obs, actions = type(self).__name__, self.observation_space, self.action_space
        if not isinstance(actions, spaces.Discrete):
            raise ValueError(f"{name} needs a Discrete action space, got {actions}")
        if not isinstance(obs, spaces.Box) or len(obs.shape) != 1:
            raise ValueError(f"{name} needs a flat Box observation space, got {obs}")
        return int(obs.shape[0]), int(actions.n)

    def _get_constructor_parameters(self) -> dict[str, Any]:
        kept = {name: getattr(self, name) for name in self.KEPT}
        return super()._get_constructor_parameters() | kept | {"lr_schedule": self._dummy_schedule}


class MonteCarloAC(A2C):
    """On-policy Monte Carlo actor-critic (the paper's Table 2) as an A2C whose rollout is one
    whole day (``n_steps`` = horizon, one env) and whose GAE lambda is 1: each update uses
    the complete episode's discounted returns. No gradient clipping when ``max_grad_norm`` is
    ``inf`` (the norm is still logged: :class:`~nutribench.agents.training_log.GradNormProbe`).
    SB3's ``A2C`` unchanged."""


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
        with warnings.catch_warnings():
            if self.replay_buffer_class is NStepReplayBuffer and kwargs.get("n_steps") == self.n_steps:
                warnings.filterwarnings(
                    "ignore", message=r"`n_steps=\d+` is ignored because a custom", category=UserWarning
                )
            super()._setup_model()

    def train(self, gradient_steps: int, batch_size: int = 100) -> None:
        self.policy.set_training_mode(True)
        self._update_learning_rate(self.policy.optimizer)
        losses, grad_norms, q_means = [], [], []
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]
            discounts = data.discounts if data.discounts is not None else self.gamma
            next_obs = data.next_observations
            with th.no_grad():
                target = double_dqn_target(
                    self.q_net(next_obs), self.q_net_target(next_obs), data.rewards, data.dones, discounts
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
        for key, values in (("loss", losses), ("q_mean", q_means), ("grad_norm", grad_norms)):
            self.logger.record(f"train/{key}", float(np.mean(values)))


class PPOWithGradNorm(PPO):
    """SB3 ``PPO`` unchanged, built without SB3's minibatch-size warning; its diagnostics'
    ``grad_norm`` (the mean over an update's gradient steps of the norm before clipping) is
    read by :class:`~nutribench.agents.training_log.GradNormProbe`, as on any on-policy model.
    Its saved models are SB3 ``PPO`` models (the name is kept: model files name it)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        # SB3 warns when batch_size does not divide n_steps; whole days per rollout matter more
        # here than equal minibatches (500 = 7 x 64 + 52). Silenced while it builds, not in the caller.
        with warnings.catch_warnings():
            warnings.filterwarnings(
                "ignore", message="You have specified a mini-batch size", module="stable_baselines3"
            )
            super().__init__(*args, **kwargs)
