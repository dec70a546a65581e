"""PPO: SB3's ``PPO`` (clipped surrogate) on the shared actor-critic backbone
(:func:`~nutribench.agents.algos.shared_actor_critic_kwargs`), unchanged (its gradient norm is
read by the diagnostics' probe, :class:`~nutribench.agents.training_log.GradNormProbe`); plain
SB3's ``PPO`` loads and acts with its models. Its optimisation fields
(:class:`~nutribench.agents.config.PPOFields`) and constructor arguments
(:meth:`~nutribench.agents.config.AgentBase.own_settings`, PPOFields' values) are shared with GRU-PPO."""

from __future__ import annotations

from typing import Literal

from nutribench.agents.config import FeedForward, PPOFields
from nutribench.agents.registry import Algorithm, ModelArguments, lazy_attributes


class PPOConfig(FeedForward, PPOFields):
    """PPO, clipped surrogate, shared actor-critic."""

    algo: Literal["ppo"]


def ppo_model_arguments(cfg: PPOConfig, horizon: int) -> ModelArguments:
    """PPO on the shared actor-critic."""
    from nutribench.agents.algos import shared_actor_critic_kwargs
    from nutribench.agents.sb3_models import PPOWithGradNorm

    return PPOWithGradNorm, dict(
        policy="MlpPolicy", **cfg.own_settings(), policy_kwargs=shared_actor_critic_kwargs(cfg.net_arch)
    )


#: its SB3 class, which imports torch: it lives in :mod:`nutribench.agents.sb3_models` and is
#: found here too, imported when first asked for (the ``load`` below names it)
__getattr__ = lazy_attributes(__name__, PPOWithGradNorm="nutribench.agents.sb3_models")

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
