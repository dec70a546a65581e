"""MC: on-policy Monte Carlo actor-critic (the paper's Table 2), SB3's ``A2C`` with a rollout
of exactly one day and GAE lambda = 1, i.e. one gradient step per complete episode on
full-episode returns minus a value baseline; Adam. Actor and critic share one backbone
(:func:`~nutribench.agents.algos.shared_actor_critic_kwargs`). Plain SB3's ``A2C`` loads and
acts with its models."""

from __future__ import annotations

from typing import Literal

from nutribench.agents.config import FeedForward, GradNorm, NonNegFloat, PosFloat
from nutribench.agents.registry import Algorithm, ModelArguments, lazy_attributes


class MCConfig(FeedForward):
    """Monte Carlo actor-critic: one update per complete episode, GAE with lambda = 1."""

    algo: Literal["mc"]
    learning_rate: PosFloat
    gae_lambda: Literal[1.0]
    ent_coef: NonNegFloat
    vf_coef: PosFloat
    max_grad_norm: GradNorm


def mc_arguments(cfg: MCConfig, horizon: int) -> ModelArguments:
    """MC: an A2C whose rollout is one whole day, GAE lambda 1, Adam, no advantage normalisation."""
    from nutribench.agents.algos import shared_actor_critic_kwargs
    from nutribench.agents.sb3_models import MonteCarloAC

    return MonteCarloAC, dict(
        policy="MlpPolicy",
        n_steps=horizon,
        **cfg.own_settings(),  # learning_rate, gae_lambda (1), ent_coef, vf_coef, max_grad_norm
        use_rms_prop=False,
        normalize_advantage=False,
        policy_kwargs=shared_actor_critic_kwargs(cfg.net_arch),
    )


#: its SB3 class, which imports torch: it lives in :mod:`nutribench.agents.sb3_models` and is
#: found here too, imported when first asked for (the ``load`` below names it)
__getattr__ = lazy_attributes(__name__, MonteCarloAC="nutribench.agents.sb3_models")

ALGORITHM = Algorithm(
    "mc",
    MCConfig,
    arguments=f"{__name__}:mc_arguments",
    load=f"{__name__}:MonteCarloAC",
    plain="stable_baselines3.A2C",
    label="MC",
    color="#8c564b",
    order=1,
    batched="nutribench.engine.mc:BatchedMC",
)
