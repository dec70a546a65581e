"""The paper's five agents on Stable-Baselines3, their config files, and one interface:
:func:`train`, :func:`evaluate`, :func:`eval_food_streams` (test days),
:func:`validation_food_streams` (validation days), :class:`TrainedAgent`."""

from nutribench.agents.api import (
    EvalResult,
    TrainedAgent,
    eval_food_streams,
    evaluate,
    train,
    validation_food_streams,
)
from nutribench.agents.config import list_agent_configs, load_agent_config

__all__ = [
    "EvalResult",
    "TrainedAgent",
    "eval_food_streams",
    "evaluate",
    "list_agent_configs",
    "load_agent_config",
    "train",
    "validation_food_streams",
]
