"""PPO: SB3's ``PPO`` (clipped surrogate) on the shared actor-critic backbone
(:func:`~nutribench.agents.algos.shared_actor_critic_kwargs`), unchanged (its gradient norm is
read by the diagnostics' probe, :class:`~nutribench.agents.training_log.GradNormProbe`); plain
SB3's ``PPO`` loads and acts with its models. Its optimisation fields
(:class:`~nutribench.agents.config.PPOFields`) and constructor arguments
(:func:`~nutribench.agents.algos.ppo_arguments`) are shared with GRU-PPO."""

from __future__ import annotations

import warnings
from typing import Any, Literal

from stable_baselines3 import PPO
from stable_baselines3.common.base_class import BaseAlgorithm

from nutribench.agents.algos import ppo_arguments, shared_actor_critic_kwargs
from nutribench.agents.config import FeedForward, PPOFields
from nutribench.agents.registry import Algorithm


class PPOConfig(FeedForward, PPOFields):
    """PPO, clipped surrogate, shared actor-critic."""

    algo: Literal["ppo"]


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


def ppo_model_arguments(cfg: PPOConfig, horizon: int) -> tuple[type[BaseAlgorithm], dict[str, Any]]:
    """PPO on the shared actor-critic."""
    return PPOWithGradNorm, dict(
        policy="MlpPolicy", **ppo_arguments(cfg), policy_kwargs=shared_actor_critic_kwargs(cfg.net_arch)
    )


ALGORITHM = Algorithm(
    "ppo",
    PPOConfig,
    arguments=f"{__name__}:ppo_model_arguments",
    load=f"{__name__}:PPOWithGradNorm",
    plain="stable_baselines3.PPO",
    label="PPO",
    color="#2ca02c",
    order=3,
    batched="nutribench.engine.ppo:BatchedPPO",
    bare=(("stable_baselines3:PPO", "bare SB3 PPO"),),
)
