"""The paper's five agents on Stable-Baselines3, their config files, and one interface:
:func:`train`, :func:`evaluate`, :func:`eval_food_streams` (test days),
:func:`validation_food_streams` (validation days), :class:`TrainedAgent`.

These names are imported when first asked for: importing a submodule (the config files'
:mod:`nutribench.agents.config`, which every command reads before it starts) imports neither
torch nor Stable-Baselines3, which :mod:`nutribench.agents.api` does."""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from nutribench.agents.api import EvalResult, TrainedAgent, evaluate, train
    from nutribench.agents.config import list_agent_configs, load_agent_config
    from nutribench.agents.days import eval_food_streams, validation_food_streams

#: each public name and the submodule that holds it
_HOMES = {
    "EvalResult": "api",
    "TrainedAgent": "api",
    "eval_food_streams": "days",
    "evaluate": "api",
    "list_agent_configs": "config",
    "load_agent_config": "config",
    "train": "api",
    "validation_food_streams": "days",
}

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


def __getattr__(name: str) -> Any:
    """A public name of the package, from its submodule (imported now); a submodule, as ever."""
    if name in _HOMES:
        return getattr(importlib.import_module(f"{__name__}.{_HOMES[name]}"), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
