"""What the algorithms on Stable-Baselines3 share: how a model is built from a config
(:func:`build_model`, from the class and arguments its registry entry's ``arguments`` gives),
the shared actor-critic backbone, PPO's arguments, and the entropy of a day's policy.

Each built-in algorithm (its config model, arguments function and SB3 class) is one module of
:mod:`nutribench.agents.builtin`; its names are found here too, as before
(``nutribench.agents.algos.DoubleDQN``).

The feedforward actor-critics share one backbone between actor and critic (:class:`Backbone`,
the shared features extractor; SB3 2.x no longer shares ``net_arch`` layers), with linear
policy and value heads on it: "shared actor-critic, 1 value head" (the paper's Tables 2 and 4).
"""

from __future__ import annotations

import inspect
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, create_mlp
from stable_baselines3.common.vec_env import VecEnv
from torch import nn

import nutribench.agents.registry as registry
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


def __getattr__(name: str) -> Any:
    """The built-in algorithms' classes and functions (``MonteCarloAC``, ``DoubleDQN``,
    ``double_dqn_target``, ``PPOWithGradNorm``, ``mc_arguments``, ...): each lives in its
    algorithm's module (:mod:`nutribench.agents.builtin`) and is found here too, as before."""
    return registry.builtin_attribute(__name__, name)


def episode_entropy(model: Any, obs: np.ndarray) -> float | None:
    """Mean policy entropy (nats) over one episode's observations ``(T, obs_dim)`` as the
    policy saw them (normalised), from the first step of the day; None for a policy that is
    not stochastic (DDQN's epsilon-greedy Q-values) or whose distribution cannot be read. An
    algorithm with a policy of its own says how (``day_entropy``: discrete SAC, GRU-PPO); SB3's
    actor-critic policies (MC, PPO, any plug-in built on them) share one way, and sb3-contrib's
    recurrent policies (``get_distribution(obs, lstm_states, episode_starts)``) are stepped
    through the day from a zero state, as they acted."""
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
