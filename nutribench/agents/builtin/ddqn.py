"""DDQN: SB3's ``DQN`` whose target is the double-DQN one (the online net picks
``argmax_a Q(s', a)``, the target net values it), with SB3's n-step replay, a linear
learning-rate schedule and hard target copies. Plain SB3's ``DQN`` loads and acts with its
models."""

from __future__ import annotations

from typing import Literal

from pydantic import model_validator

from nutribench.agents.config import FeedForward, GradNorm, NonNegInt, PosFloat, PosInt, Prob, Transitions
from nutribench.agents.registry import Algorithm, ModelArguments, lazy_attributes, no_replay_scaling
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


def ddqn_arguments(cfg: DDQNConfig, horizon: int) -> ModelArguments:
    """Double DQN: a linear learning-rate schedule, hard target copies (tau 1)."""
    from stable_baselines3.common.utils import LinearSchedule

    from nutribench.agents.sb3_models import DoubleDQN

    own = cfg.own_settings()  # the rest are DoubleDQN's arguments of the same names
    rates = LinearSchedule(own.pop("learning_rate_start"), own.pop("learning_rate_end"), end_fraction=1.0)
    own["n_steps"] = own.pop("n_step")
    return DoubleDQN, dict(
        policy="MlpPolicy", learning_rate=rates, **own, tau=1.0, policy_kwargs=dict(net_arch=list(cfg.net_arch))
    )


#: its SB3 class and target, which import torch: they live in :mod:`nutribench.agents.sb3_models`
#: and are found here too, imported when first asked for (the ``load`` below names one)
__getattr__ = lazy_attributes(
    __name__, DoubleDQN="nutribench.agents.sb3_models", double_dqn_target="nutribench.agents.sb3_models"
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
