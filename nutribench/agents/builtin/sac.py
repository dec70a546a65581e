"""SAC: discrete-action soft actor-critic with a fixed temperature,
:class:`~nutribench.agents.sac.DiscreteSAC` (its policy, buffer and update live in
:mod:`nutribench.agents.sac`), which also loads its saved models."""

from __future__ import annotations

from typing import Literal

from nutribench.agents.config import FeedForward, NonNegFloat, NonNegInt, PosFloat, PosInt, Prob, Transitions
from nutribench.agents.registry import Algorithm, ModelArguments, lazy_attributes, no_replay_scaling


class SACConfig(FeedForward):
    """Discrete-action SAC, fixed temperature."""

    algo: Literal["sac"]
    actor_learning_rate: PosFloat
    critic_learning_rate: PosFloat
    buffer_size: Transitions
    learning_starts: NonNegInt
    batch_size: Transitions
    tau: Prob
    alpha: NonNegFloat
    train_freq: PosInt
    gradient_steps: PosInt


def sac_arguments(cfg: SACConfig, horizon: int) -> ModelArguments:
    """Discrete SAC, fixed temperature."""
    from nutribench.agents.sac import DiscreteSAC

    return DiscreteSAC, dict(policy="MlpPolicy", **cfg.own_settings(), net_arch=list(cfg.net_arch))


#: its SB3 class (imported when first asked for: it imports torch), found here as before
__getattr__ = lazy_attributes(__name__, DiscreteSAC="nutribench.agents.sac")

ALGORITHM = Algorithm(
    "sac",
    SACConfig,
    arguments=f"{__name__}:sac_arguments",
    load="nutribench.agents.sac:DiscreteSAC",
    plain="nutribench.agents.sac.DiscreteSAC",
    label="SAC",
    color="#d62728",
    order=4,
    batched="nutribench.engine.sac:BatchedSAC",
    batch_limits=no_replay_scaling,
    cost=5.0,
)
