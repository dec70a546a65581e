"""The five algorithms on Stable-Baselines3, built from their config models.

* **MC** (:class:`MonteCarloAC`): SB3 ``A2C`` with a rollout of exactly one day and GAE
  lambda = 1, i.e. one gradient step per complete episode on full-episode returns minus a
  value baseline; Adam.
* **DDQN** (:class:`DoubleDQN`): SB3 ``DQN`` whose target is the double-DQN one (the online
  net picks ``argmax_a Q(s', a)``, the target net values it), with SB3's n-step replay.
* **PPO** (:class:`PPOWithGradNorm`): SB3 ``PPO``; its update's gradient norm is logged.
* **SAC**: :class:`~nutribench.agents.sac.DiscreteSAC`.
* **GRU-PPO**: :class:`~nutribench.agents.gru_ppo.GRUPPO`.

MC and PPO share one backbone between actor and critic (:class:`Backbone`, the shared
features extractor; SB3 2.x no longer shares ``net_arch`` layers), with linear policy and
value heads on it: "shared actor-critic, 1 value head" (the paper's Tables 2 and 4).
"""

from __future__ import annotations

import inspect
import warnings
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.common.utils import LinearSchedule
from stable_baselines3.common.vec_env import VecEnv
from torch import nn
from torch.nn import functional as F

import nutribench.agents.registry as registry
from nutribench.agents.config import DDQNConfig, GRUPPOConfig, MCConfig, PPOConfig, SACConfig
from nutribench.agents.gru_ppo import GRUPPO
from nutribench.agents.sac import DiscreteSAC
from nutribench.agents.sb3_train import GradNormA2C, GradNormPPO
from nutribench.config.loading import ConfigError


class Backbone(BaseFeaturesExtractor):
    """MLP ``obs -> net_arch[0] -> ... -> net_arch[-1]`` with ReLU, shared by actor and critic."""

    def __init__(self, observation_space: gym.spaces.Box, net_arch: list[int]):
        super().__init__(observation_space, features_dim=int(net_arch[-1]))
        # output_dim=-1: no output layer, the MLP ends on the last hidden layer's ReLU
        layers = create_mlp(int(np.prod(observation_space.shape)), -1, list(net_arch), nn.ReLU)
        self.net = nn.Sequential(nn.Flatten(), *layers)

    def forward(self, observations: th.Tensor) -> th.Tensor:
        return self.net(observations)


def shared_actor_critic_kwargs(net_arch: list[int]) -> dict[str, Any]:
    """Policy kwargs for a shared ``net_arch`` backbone with linear policy and value heads."""
    return dict(
        features_extractor_class=Backbone,
        features_extractor_kwargs=dict(net_arch=list(net_arch)),
        share_features_extractor=True,
        net_arch=dict(pi=[], vf=[]),
        optimizer_class=th.optim.Adam,
    )


# ---------------------------------------------------------------------------- MC
class MonteCarloAC(GradNormA2C):
    """On-policy Monte Carlo actor-critic (the paper's Table 2) as an A2C whose rollout is one
    whole day (``n_steps`` = horizon, one env) and whose GAE lambda is 1: each update uses
    the complete episode's discounted returns. No gradient clipping when ``max_grad_norm`` is
    ``inf`` (the norm is still logged: :class:`~nutribench.agents.sb3_train.GradNormA2C`)."""


# ---------------------------------------------------------------------------- PPO
class PPOWithGradNorm(GradNormPPO):
    """SB3 ``PPO`` unchanged; each update also logs ``train/grad_norm``, the mean over its
    gradient steps of the norm before clipping (:class:`~nutribench.agents.sb3_train.GradNormPPO`).
    Its saved models are SB3 ``PPO`` models."""


# ---------------------------------------------------------------------------- DDQN
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


# ---------------------------------------------------------------------------- builders
#: Mixed into the job seed for the action space's random stream (see :func:`build_model`).
ACTION_STREAM_SALT = 27_182


def build_model(
    cfg: Any, env: VecEnv, seed: int, horizon: int, cls: type[BaseAlgorithm] | None = None
) -> BaseAlgorithm:
    """The SB3 algorithm object for config ``cfg`` on ``env`` (CPU, seeded, silent).

    ``cls`` replaces the config's class by another taking the same arguments (the speed
    benchmark times SB3's vanilla ``DQN`` with DDQN's hyperparameters this way)."""
    default_cls, kwargs = model_arguments(cfg, horizon)
    model = (cls or default_cls)(env=env, seed=seed, device="cpu", verbose=0, gamma=cfg.gamma, **kwargs)
    # SB3 seeds the action space with the job seed, and the env draws each day's foods from a
    # generator seeded the same way: one PCG64 stream twice, so that SB3's "random" actions
    # (DDQN's warm-up and epsilon steps, SAC's warm-up) were a function of the food offered
    # (eat exactly when its index is in the upper half). The action space gets its own stream.
    model.action_space.seed(int(np.random.SeedSequence([ACTION_STREAM_SALT, int(seed)]).generate_state(1)[0]))
    # Without a logger of its own, every ``learn()`` makes SB3 create an empty folder
    # tempdir/SB3-<date> (its default logger's folder), one per job: thousands in /tmp.
    model.set_logger(Logger(folder=None, output_formats=[]))
    return model


def ppo_arguments(cfg: PPOConfig | GRUPPOConfig) -> dict[str, Any]:
    """The constructor arguments PPO and GRU-PPO share (GRU-PPO's update is PPO's)."""
    return dict(
        learning_rate=cfg.learning_rate,
        n_steps=cfg.n_steps,
        batch_size=cfg.batch_size,
        n_epochs=cfg.n_epochs,
        gae_lambda=cfg.gae_lambda,
        clip_range=cfg.clip_range,
        ent_coef=cfg.ent_coef,
        vf_coef=cfg.vf_coef,
        max_grad_norm=cfg.max_grad_norm,
        normalize_advantage=cfg.normalize_advantage,
    )


def model_arguments(cfg: Any, horizon: int) -> tuple[type[BaseAlgorithm], dict[str, Any]]:
    """The algorithm class of config ``cfg`` and its constructor arguments (all but env,
    seed, device, verbosity and gamma, which :func:`build_model` adds): its registry entry's
    ``arguments`` (:mod:`nutribench.agents.registry`)."""
    entry = registry.algorithm(cfg)
    if entry.arguments is None:
        raise ConfigError(
            f"algorithm {entry.algo!r}: its registry entry has no arguments, so build_model cannot build it"
        )
    return registry.import_entry_point(entry.arguments)(cfg, horizon)


def mc_arguments(cfg: MCConfig, horizon: int) -> tuple[type[BaseAlgorithm], dict[str, Any]]:
    """MC: an A2C whose rollout is one whole day, GAE lambda 1, Adam, no advantage normalisation."""
    return MonteCarloAC, dict(
        policy="MlpPolicy",
        n_steps=horizon,
        learning_rate=cfg.learning_rate,
        gae_lambda=1.0,
        ent_coef=cfg.ent_coef,
        vf_coef=cfg.vf_coef,
        max_grad_norm=cfg.max_grad_norm,
        use_rms_prop=False,
        normalize_advantage=False,
        policy_kwargs=shared_actor_critic_kwargs(cfg.net_arch),
    )


def ppo_model_arguments(cfg: PPOConfig, horizon: int) -> tuple[type[BaseAlgorithm], dict[str, Any]]:
    """PPO on the shared actor-critic."""
    # SB3 warns when batch_size does not divide n_steps; whole days per rollout matter more
    # here than equal minibatches (500 = 7 x 64 + 52).
    warnings.filterwarnings("ignore", message="You have specified a mini-batch size", module="stable_baselines3")
    return PPOWithGradNorm, dict(
        policy="MlpPolicy", **ppo_arguments(cfg), policy_kwargs=shared_actor_critic_kwargs(cfg.net_arch)
    )


def gru_ppo_arguments(cfg: GRUPPOConfig, horizon: int) -> tuple[type[BaseAlgorithm], dict[str, Any]]:
    """GRU-PPO: PPO's arguments, the recurrent policy's sizes and whether it carries its state."""
    return GRUPPO, dict(
        **ppo_arguments(cfg), hidden_size=cfg.hidden_size, sequence_length=cfg.sequence_length, memory=cfg.memory
    )


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


def sac_arguments(cfg: SACConfig, horizon: int) -> tuple[type[BaseAlgorithm], dict[str, Any]]:
    """Discrete SAC, fixed temperature."""
    return DiscreteSAC, dict(
        policy="MlpPolicy",
        actor_learning_rate=cfg.actor_learning_rate,
        critic_learning_rate=cfg.critic_learning_rate,
        buffer_size=cfg.buffer_size,
        learning_starts=cfg.learning_starts,
        batch_size=cfg.batch_size,
        tau=cfg.tau,
        alpha=cfg.alpha,
        train_freq=cfg.train_freq,
        gradient_steps=cfg.gradient_steps,
        net_arch=list(cfg.net_arch),
    )


def episode_entropy(model: Any, obs: np.ndarray) -> float | None:
    """Mean policy entropy (nats) over one episode's observations ``(T, obs_dim)`` as the
    policy saw them (normalised), from the first step of the day; None for a policy that is
    not stochastic or whose distribution cannot be read. An algorithm with a policy of its own
    says how (``day_entropy``: DDQN, discrete SAC, GRU-PPO); SB3's actor-critic policies (MC,
    PPO, any plug-in built on them) share one way, and sb3-contrib's recurrent policies
    (``get_distribution(obs, lstm_states, episode_starts)``) are stepped through the day from
    a zero state, as they acted."""
    own = getattr(model, "day_entropy", None)
    if own is not None:
        return own(obs)
    policy = getattr(model, "policy", None)
    get_distribution = getattr(policy, "get_distribution", None)
    if get_distribution is None:
        return None
    x = th.as_tensor(obs, dtype=th.float32, device=getattr(policy, "device", "cpu"))
    try:
        with th.no_grad():
            if "lstm_states" in inspect.signature(get_distribution).parameters:
                shape = policy.lstm_hidden_state_shape  # (layers, 1, hidden): one sequence
                zeros = th.zeros(shape, device=x.device)
                starts = th.zeros(len(x), device=x.device)
                starts[0] = 1.0
                dist, _ = get_distribution(x, (zeros, zeros.clone()), starts)
            else:
                dist = get_distribution(x)
            return float(dist.entropy().mean())
    except (NotImplementedError, TypeError, AttributeError, ValueError, RuntimeError):
        return None  # a policy without a readable distribution: NULL, never a crashed job
