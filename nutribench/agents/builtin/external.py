"""``external``: an agent implemented outside nutribench, a plug-in named by its config's
entry point (no builder of its own: :func:`nutribench.agents.registry.make_model` calls the
entry point; its loader is the ``load`` beside it, imported only when the user names it)."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from nutribench.agents.config import Discount, Flag, Name, Version
from nutribench.agents.registry import Algorithm

EntryPoint = Annotated[
    str, Field(pattern=r"^[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*:[A-Za-z_][A-Za-z0-9_]*$")
]


class ExternalConfig(BaseModel):
    """An agent implemented outside nutribench: a plug-in named by its entry point.

    ``entry_point = "package.module:make_agent"`` names a function
    ``make_agent(params: dict, env: VecEnv, seed: int)`` returning an object with SB3's
    algorithm surface (``learn(total_timesteps)``, ``predict(obs, state, episode_start,
    deterministic)``, ``save(path)``); the same module has ``load(path)`` for a saved one.
    ``params`` is free (it is hashed with the rest of the file). The other fields have the
    defaults stated here. An external config without ``entry_point`` describes an agent whose
    results were recorded (:class:`nutribench.Recorder`, ``nutribench evaluate``): it cannot be
    trained by ``nutribench run``.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    algo: Literal["external"]
    name: Name
    version: Version
    description: str
    entry_point: EntryPoint | None = Field(default=None, description="package.module:make_agent")
    params: dict[str, Any] = Field(default_factory=dict, description="passed to make_agent as its first argument")
    normalize_obs: Flag = Field(default=False, description="wrap the env in VecNormalize(norm_obs=True)")
    normalize_reward: Flag = Field(default=False, description="wrap the env in VecNormalize(norm_reward=True)")
    gamma: Discount = Field(default=0.99, description="VecNormalize's return discount")


ALGORITHM = Algorithm("external", ExternalConfig, build=None)
