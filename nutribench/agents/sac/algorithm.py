"""Discrete SAC, the algorithm: the pure maths of the update, and the SB3 off-policy algorithm around it."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
import torch as th
from gymnasium import spaces
from stable_baselines3.common.buffers import ReplayBuffer
from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm
from stable_baselines3.common.policies import BasePolicy
from stable_baselines3.common.type_aliases import GymEnv, Schedule
from stable_baselines3.common.utils import FloatSchedule, polyak_update, update_learning_rate
from torch.nn import functional as F

from nutribench.agents.sac.policy import DiscreteSACPolicy


def soft_value(
    q1_next: th.Tensor, q2_next: th.Tensor, probs_next: th.Tensor, log_probs_next: th.Tensor, alpha: float
) -> th.Tensor:
    """Soft state value as an expectation under the policy.

    ``V(s) = sum_a pi(a|s) * (min(Q1, Q2)(s, a) - alpha * log pi(a|s))``.

    :param q1_next: ``(batch, n_actions)`` first (target) critic at the next states.
    :param q2_next: ``(batch, n_actions)`` second (target) critic at the next states.
    :param probs_next: ``(batch, n_actions)`` policy probabilities ``pi(a|s')``.
    :param log_probs_next: ``(batch, n_actions)`` their logarithms (pass ``log_softmax`` of the
        logits rather than ``log(probs)``, which is ``-inf`` where a probability underflows).
    :param alpha: entropy temperature.
    :return: ``(batch,)`` soft values.
    """
    min_q = th.min(q1_next, q2_next)
    return (probs_next * (min_q - alpha * log_probs_next)).sum(dim=-1)


def soft_bellman_target(rewards: th.Tensor, dones: th.Tensor, next_values: th.Tensor, gamma: float) -> th.Tensor:
    """1-step soft Bellman target ``r + gamma * (1 - done) * V(s')`` (all inputs flattened to ``(batch,)``)."""
    return rewards.reshape(-1) + gamma * (1.0 - dones.reshape(-1)) * next_values.reshape(-1)


class DiscreteSAC(OffPolicyAlgorithm):
    """Soft Actor-Critic with a categorical actor (the paper's Table 5, "SAC (discrete actions)").

    :param policy: ``"MlpPolicy"`` or a policy class (:class:`DiscreteSACPolicy` or a subclass).
    :param env: the environment (a Gymnasium env or an SB3 ``VecEnv``, e.g.
        ``VecNormalize(NutriRLSB3VecEnv(...), norm_obs=True, norm_reward=False)``).
    :param actor_learning_rate: Adam learning rate of the actor (float or SB3 schedule).
    :param critic_learning_rate: Adam learning rate of the twin critics (float or SB3 schedule).
    :param buffer_size: replay buffer capacity (transitions).
    :param learning_starts: env steps of uniform random actions before the first gradient step.
    :param batch_size: transitions per gradient step.
    :param tau: Polyak coefficient of the target critics (``targ <- tau * online + (1 - tau) * targ``).
    :param gamma: discount factor.
    :param alpha: entropy temperature, fixed.
    :param train_freq: collect this many steps (of all envs at once) between updates, or a
        ``(n, "step" | "episode")`` tuple.
    :param gradient_steps: gradient steps after each collection (-1: as many as env steps collected).
    :param net_arch: hidden layer sizes of the actor and of each critic.
    :param replay_buffer_class: replay buffer class (default SB3's ``ReplayBuffer``).
    :param replay_buffer_kwargs: keyword arguments of the replay buffer.
    :param policy_kwargs: extra keyword arguments of the policy (``net_arch`` is set from ``net_arch``).
    :param stats_window_size: episodes averaged in the rollout logs.
    :param tensorboard_log: tensorboard log folder (None: none).
    :param seed: seed of Python, NumPy, PyTorch, the action space and the env.
    :param device: torch device.
    :param verbose: 0 silent, 1 info, 2 debug.
    :param _init_setup_model: build the networks now (SB3's ``load`` passes False).

    Logged each update: ``train/actor_loss``, ``train/critic_loss``, ``train/entropy`` (mean
    policy entropy on the batch, nats), ``train/q_mean`` (mean of the twin critics' minimum
    at the batch's actions), ``train/alpha``, ``train/n_updates``.
    """

    policy_aliases: ClassVar[dict[str, type[BasePolicy]]] = {"MlpPolicy": DiscreteSACPolicy}
    policy: DiscreteSACPolicy

    def __init__(
        self,
        policy: str | type[DiscreteSACPolicy] = "MlpPolicy",
        env: GymEnv | str | None = None,
        actor_learning_rate: float | Schedule = 1e-4,
        critic_learning_rate: float | Schedule = 1e-3,
        buffer_size: int = 100_000,
        learning_starts: int = 128,
        batch_size: int = 128,
        tau: float = 0.005,
        gamma: float = 0.99,
        alpha: float = 0.2,
        train_freq: int | tuple[int, str] = 1,
        gradient_steps: int = 1,
        net_arch: Sequence[int] = (256, 128),
        replay_buffer_class: type[ReplayBuffer] | None = None,
        replay_buffer_kwargs: dict[str, Any] | None = None,
        policy_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        seed: int | None = None,
        device: th.device | str = "cpu",
        verbose: int = 0,
        _init_setup_model: bool = True,
    ):
        policy_kwargs = dict(policy_kwargs or {})
        policy_kwargs.setdefault("net_arch", [int(n) for n in net_arch])
        super().__init__(
            policy,
            env,  # type: ignore[arg-type]
            learning_rate=critic_learning_rate,  # SB3's `lr_schedule` is the critic's
            buffer_size=buffer_size,
            learning_starts=learning_starts,
            batch_size=batch_size,
            tau=tau,
            gamma=gamma,
            train_freq=train_freq,
            gradient_steps=gradient_steps,
            replay_buffer_class=replay_buffer_class,
            replay_buffer_kwargs=replay_buffer_kwargs,
            policy_kwargs=policy_kwargs,
            stats_window_size=stats_window_size,
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            seed=seed,
            sde_support=False,
            supported_action_spaces=(spaces.Discrete,),
            support_multi_env=True,
        )
        if alpha < 0:
            raise ValueError(f"alpha must be >= 0, got {alpha}")
        self.actor_learning_rate = actor_learning_rate
        self.critic_learning_rate = critic_learning_rate
        self.alpha = float(alpha)
        self.net_arch = [int(n) for n in net_arch]
        if _init_setup_model:
            self._setup_model()

    # ---- set-up ----

    def _setup_model(self) -> None:
        super()._setup_model()
        self.actor_lr_schedule = FloatSchedule(self.actor_learning_rate)
        self.critic_lr_schedule = self.lr_schedule
        self._update_learning_rates()

    def _update_learning_rates(self) -> tuple[float, float]:
        """Set each optimiser's rate from its schedule; returns ``(actor_lr, critic_lr)``."""
        progress = self._current_progress_remaining
        actor_lr, critic_lr = self.actor_lr_schedule(progress), self.critic_lr_schedule(progress)
        update_learning_rate(self.policy.actor_optimizer, actor_lr)
        update_learning_rate(self.policy.critic_optimizer, critic_lr)
        return actor_lr, critic_lr

    # ---- the update, in readable pieces ----

    def critic_target_values(self, next_obs: th.Tensor, rewards: th.Tensor, dones: th.Tensor) -> th.Tensor:
        """1-step soft Bellman targets ``r + gamma (1 - done) V(s')`` (no gradient), ``(batch,)``."""
        with th.no_grad():
            probs_next, log_probs_next = self.policy.action_log_probs(next_obs)
            q1_next, q2_next = self.policy.q_values(next_obs, target=True)
            v_next = soft_value(q1_next, q2_next, probs_next, log_probs_next, self.alpha)
            return soft_bellman_target(rewards, dones, v_next, self.gamma)

    def critic_loss(self, obs: th.Tensor, actions: th.Tensor, targets: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``MSE(Q1(s,a), y) + MSE(Q2(s,a), y)`` and the mean of ``min(Q1, Q2)(s,a)`` (for logging)."""
        q1, q2 = self.policy.q_values(obs)
        a = actions.long().reshape(-1, 1)
        q1_a, q2_a = q1.gather(1, a).squeeze(1), q2.gather(1, a).squeeze(1)
        return F.mse_loss(q1_a, targets) + F.mse_loss(q2_a, targets), th.min(q1_a, q2_a).detach().mean()

    def actor_loss(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        """``E_s sum_a pi(a|s) (alpha log pi(a|s) - min Q(s,a))`` (critics detached) and the mean entropy."""
        probs, log_probs = self.policy.action_log_probs(obs)
        with th.no_grad():
            q1, q2 = self.policy.q_values(obs)
            min_q = th.min(q1, q2)
        loss = (probs * (self.alpha * log_probs - min_q)).sum(dim=-1).mean()
        entropy = -(probs * log_probs).sum(dim=-1).mean()
        return loss, entropy.detach()

    def train(self, gradient_steps: int, batch_size: int = 128) -> None:
        self.policy.set_training_mode(True)
        actor_lr, critic_lr = self._update_learning_rates()
        logged: dict[str, list[float]] = {"actor_loss": [], "critic_loss": [], "entropy": [], "q_mean": []}
        for _ in range(gradient_steps):
            data = self.replay_buffer.sample(batch_size, env=self._vec_normalize_env)  # type: ignore[union-attr]

            # critic step
            targets = self.critic_target_values(data.next_observations, data.rewards, data.dones)
            critic_loss, q_mean = self.critic_loss(data.observations, data.actions, targets)
            self.policy.critic_optimizer.zero_grad()
            critic_loss.backward()
            self.policy.critic_optimizer.step()

            # actor step (against the just-updated critics)
            actor_loss, entropy = self.actor_loss(data.observations)
            self.policy.actor_optimizer.zero_grad()
            actor_loss.backward()
            self.policy.actor_optimizer.step()

            # target critics
            polyak_update(self.policy.critic.parameters(), self.policy.critic_target.parameters(), self.tau)

            for values, value in zip(logged.values(), (actor_loss, critic_loss, entropy, q_mean)):
                values.append(value.item())

        self._n_updates += gradient_steps
        self.logger.record("train/n_updates", self._n_updates, exclude="tensorboard")
        for key, values in logged.items():
            self.logger.record(f"train/{key}", float(np.mean(values)))
        self.logger.record("train/alpha", self.alpha)
        self.logger.record("train/actor_learning_rate", actor_lr)
        self.logger.record("train/critic_learning_rate", critic_lr)

    # ---- inspection ----

    def action_entropy(self, observation: np.ndarray) -> np.ndarray:
        """Entropy (nats) of ``pi(.|s)`` for a batch ``(n, obs_dim)`` (or one ``(obs_dim,)``) of
        observations, as the policy sees them (already normalised when the env is wrapped in
        ``VecNormalize``)."""
        obs, vectorized = self.policy.obs_to_tensor(observation)
        with th.no_grad():
            entropy = self.policy.entropy(obs).cpu().numpy()
        return entropy if vectorized else entropy[0]

    def day_entropy(self, obs: np.ndarray) -> float:
        """Mean entropy over one day's observations ``(T, obs_dim)`` (the training record's)."""
        return float(self.action_entropy(obs).mean())

    # ---- SB3 plumbing ----

    def _excluded_save_params(self) -> list[str]:
        return [*super()._excluded_save_params(), "actor_lr_schedule", "critic_lr_schedule"]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy", "policy.actor_optimizer", "policy.critic_optimizer"], []
