"""GRU-PPO: PPO with the recurrent two-GRU policy of the paper's Table 6,
:class:`~nutribench.agents.gru_ppo.GRUPPO` (its policy, buffer and algorithm live in
:mod:`nutribench.agents.gru_ppo`), which also loads its saved models. Its optimisation fields
(:class:`~nutribench.agents.config.PPOFields`) and constructor arguments
(:meth:`~nutribench.agents.config.AgentBase.own_settings`) are PPO's with its own."""

from __future__ import annotations

from typing import Any, Literal

from pydantic import Field, SerializerFunctionWrapHandler, model_serializer, model_validator

from nutribench.agents.config import AgentBase, Flag, HiddenSize, PosInt, PPOFields
from nutribench.agents.registry import Algorithm, ModelArguments, lazy_attributes
from nutribench.config.sizes import rollout_bytes, too_large


class GRUPPOConfig(AgentBase, PPOFields):
    """PPO with the recurrent two-GRU policy of the paper's Table 6 (heads fixed by the paper)."""

    algo: Literal["gru_ppo"]
    hidden_size: HiddenSize
    sequence_length: PosInt
    memory: Flag = Field(
        default=True,
        description="carry the GRUs' state from step to step within a day; false: zero it before every "
        "step (no memory: the same network sees only the current observation)",
    )

    @model_serializer(mode="wrap")
    def _memory_only_when_off(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """``memory`` enters the content (and the hash) only when false, so that the files
        written before it existed keep their hash (as a regime's observation options)."""
        data = handler(self)
        if self.memory:
            data.pop("memory", None)
        return data

    @model_validator(mode="after")
    def _whole_sequences(self) -> GRUPPOConfig:
        if self.n_steps % self.sequence_length:
            raise ValueError(f"n_steps ({self.n_steps}) must be a multiple of sequence_length ({self.sequence_length})")
        return self

    @model_validator(mode="after")
    def _a_rollout_that_fits(self) -> GRUPPOConfig:
        """Refuse a rollout whose GRU states could never be held (:func:`nutribench.config.sizes.rollout_bytes`)."""
        why = too_large(
            f"n_steps = {self.n_steps:,} with hidden_size = {self.hidden_size:,}: a rollout",
            rollout_bytes(self.n_steps, self.hidden_size),
        )
        if why:
            raise ValueError(why)
        return self


def gru_ppo_arguments(cfg: GRUPPOConfig, horizon: int) -> ModelArguments:
    """GRU-PPO: PPO's arguments, the recurrent policy's sizes and whether it carries its state."""
    from nutribench.agents.gru_ppo import GRUPPO

    return GRUPPO, cfg.own_settings()  # PPO's, hidden_size, sequence_length and memory


def whole_days(cfg: GRUPPOConfig, horizon: int | None) -> str | None:
    """The batched recurrent PPO trains on whole days."""
    if horizon is not None and (cfg.sequence_length != horizon or cfg.n_steps % horizon):
        return (
            f"the batched engine trains on whole days, so sequence_length ({cfg.sequence_length}) must be the "
            f"horizon ({horizon}) and n_steps ({cfg.n_steps}) a multiple of it"
        )
    return None


#: its SB3 class (imported when first asked for: it imports torch), found here as before
__getattr__ = lazy_attributes(__name__, GRUPPO="nutribench.agents.gru_ppo")

ALGORITHM = Algorithm(
    "gru_ppo",
    GRUPPOConfig,
    arguments=f"{__name__}:gru_ppo_arguments",
    load="nutribench.agents.gru_ppo:GRUPPO",
    plain="nutribench.agents.gru_ppo.GRUPPO",
    label="GRU-PPO",
    color="#9467bd",
    order=5,
    batched="nutribench.engine.gru_ppo:BatchedGRUPPO",
    batch_limits=whole_days,
    cost=5.0,
)
