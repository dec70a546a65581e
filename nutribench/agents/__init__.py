"""The paper's five agents on Stable-Baselines3, their config files, and one interface:
:func:`train`, :func:`evaluate`, :func:`eval_food_streams` (test days),
:func:`validation_food_streams` (validation days), :class:`TrainedAgent`.

These names are imported when first asked for: importing a submodule (the config files'
:mod:`nutribench.agents.config`, which every command reads before it starts) imports neither
torch nor Stable-Baselines3, which :mod:`nutribench.agents.api` does."""

from __future__ import annotations

from typing import TYPE_CHECKING

from nutribench.agents.registry import lazy_attributes

if TYPE_CHECKING:
    from nutribench.agents.api import EvalResult, TrainedAgent, evaluate, train
    from nutribench.agents.config import list_agent_configs, load_agent_config
    from nutribench.agents.days import eval_food_streams, validation_food_streams

#: each submodule and the public names it holds
_HOMES = {
    "api": ("EvalResult", "TrainedAgent", "evaluate", "train"),
    "config": ("list_agent_configs", "load_agent_config"),
    "days": ("eval_food_streams", "validation_food_streams"),
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


#: a public name of the package, from its submodule (imported now); a submodule, as ever
__getattr__ = lazy_attributes(
    __name__, **{name: f"{__name__}.{home}" for home, names in _HOMES.items() for name in names}
)
