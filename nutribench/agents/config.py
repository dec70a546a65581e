"""Agent configurations (the paper's Tables 2-6) as versioned, validated files.

One TOML file per configuration in ``regimes/agents/`` (``<name>.toml``); the ``algo`` key
picks the config model (the one its registry entry names, :mod:`nutribench.agents.registry`),
every hyperparameter of the built-in algorithms is written out (nothing is defaulted), unknown
keys are errors, and ``name`` must equal the file name. A user adds a variant by copying a
file, changing ``name`` (and the file name) and the values, or brings an algorithm of their
own: a registered one with its own config model, or ``algo = "external"``
(:class:`~nutribench.agents.builtin.external.ExternalConfig`): an ``entry_point =
"package.module:make_agent"`` and a free ``[params]`` table.

This module holds what every config model is built from (the field types, ``AgentBase``,
``PPOFields``) and the reading, hashing and writing of the files; each built-in algorithm's
own model lives in its module of :mod:`nutribench.agents.builtin` (and is found here by name
too, ``nutribench.agents.config.MCConfig``, as before).

The content hash (:func:`agent_config_sha256`) is what the results database records next
to ``name`` and ``version``: a file changed without a version bump is refused by ``run``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any

import tomli_w
from pydantic import BaseModel, ConfigDict, Field, field_validator

import nutribench.agents.registry as registry
from nutribench.config.loading import (
    ConfigError,
    check_folder_setting,
    content_sha256,
    parse_once,
    regimes_dir,
    resolve_named_file,
    validate,
)
from nutribench.config.models import NoBool, StrictBool, Version
from nutribench.config.reading import read_config_bytes
from nutribench.config.sizes import HIDDEN_BOUND, STEPS_BOUND, TRANSITIONS_BOUND, network_bytes, too_large

# Every float hyperparameter is finite (inf or nan is refused when the file is read: a learning
# rate of inf trained and was stored as done), but a gradient norm, where inf means no clipping.
# Every number is strict about booleans (``learning_rate = true`` ran as 1.0), every switch is a
# boolean (``normalize_obs = 1`` is refused), and
# every size is bounded by what it makes the program hold (nutribench.config.sizes: derived there).
PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False), NoBool]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False), NoBool]
Prob = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False), NoBool]
GradNorm = Annotated[float, Field(gt=0, allow_inf_nan=True, description="inf: no clipping"), NoBool]
Discount = Annotated[float, Field(gt=0, le=1, allow_inf_nan=False), NoBool]
PosInt = Annotated[int, Field(ge=1), NoBool]
NonNegInt = Annotated[int, Field(ge=0), NoBool]
#: a step count that ends in a stored step number (a rollout's: the timestep of its first update)
Steps = Annotated[int, Field(ge=1), STEPS_BOUND, NoBool]
#: transitions held in memory at once (a replay buffer, a sampled batch): 52 bytes each at least
Transitions = Annotated[int, Field(ge=1), TRANSITIONS_BOUND, NoBool]
#: hidden units of the recurrent policy's two GRUs: 96 h^2 bytes at least
HiddenSize = Annotated[int, Field(ge=1), HIDDEN_BOUND, NoBool]
Flag = StrictBool
Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=64)]


class AgentBase(BaseModel):
    """Fields every agent config has."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Name
    version: Version
    description: str
    normalize_obs: Flag = Field(description="running mean/std normalisation of observations (SB3 VecNormalize)")
    normalize_reward: Flag = Field(
        description="scale rewards by a running std of the discounted return (SB3 VecNormalize); recorded returns stay raw"
    )
    gamma: Discount

    def own_settings(self) -> dict[str, Any]:
        """The values of the fields its algorithm's config adds (not those of :class:`FeedForward`,
        every agent's and the backbone's, nor ``algo``): what a built-in algorithm's constructor
        takes under the same names (PPO's :class:`PPOFields`, SAC's rates, buffer and temperature)."""
        common = {"algo", *FeedForward.model_fields}
        return {name: getattr(self, name) for name in type(self).model_fields if name not in common}


class FeedForward(AgentBase):
    """The fields of a feedforward agent: the common ones and its backbone's hidden layers."""

    net_arch: list[PosInt] = Field(min_length=1, description="hidden layers of the shared backbone, e.g. [256, 128]")

    @field_validator("net_arch")
    @classmethod
    def _a_network_that_fits(cls, widths: list[int]) -> list[int]:
        """Refuse a network whose training could never be held (:func:`nutribench.config.sizes.network_bytes`)."""
        shown = str(widths) if len(widths) <= 8 else f"{len(widths):,} layers of up to {max(widths):,} units"
        why = too_large(f"a network of {shown}", network_bytes(widths))
        if why:
            raise ValueError(why)
        return widths


class PPOFields(BaseModel):
    """PPO's optimisation fields, shared by the feedforward and the recurrent PPO."""

    learning_rate: PosFloat
    n_steps: Steps
    batch_size: Transitions
    n_epochs: PosInt
    gae_lambda: Prob
    clip_range: PosFloat
    ent_coef: NonNegFloat
    vf_coef: PosFloat
    max_grad_norm: GradNorm
    normalize_advantage: Flag


def __getattr__(name: str) -> Any:
    """The config models of the built-in algorithms (``MCConfig``, ``ExternalConfig``, ...): each
    lives in its algorithm's module (:mod:`nutribench.agents.builtin`) and is found here too, as
    it was before (code and agent files' entry points that name ``nutribench.agents.config:``)."""
    return registry.builtin_attribute(__name__, name)


def agent_folders() -> list[Path]:
    """The folders agent files are looked up in, first match wins: ``$NUTRIBENCH_AGENTS`` (one
    folder or several, separated as ``PATH`` is) before the shipped ``regimes/agents/``, so a
    folder of one's own adds to the shipped agents."""
    import os

    env = os.environ.get("NUTRIBENCH_AGENTS")
    own = [Path(p) for p in env.split(os.pathsep) if p] if env else []
    for folder in own:  # a FIFO or a device there is refused, never silently no folder
        check_folder_setting("NUTRIBENCH_AGENTS", folder, "a folder of agent files (several: separated by ':')")
    shipped = regimes_dir() / "agents"
    return [*own, *([shipped] if shipped not in own else [])]


def agents_dir() -> Path:
    """The first agent folder (:func:`agent_folders`): ``$NUTRIBENCH_AGENTS``'s first, else
    ``regimes/agents/``; where ``tune best --write`` writes by default."""
    return agent_folders()[0]


def list_agent_configs(folder: Path | None = None) -> list[str]:
    """Names of the agent config files (of ``folder``, or of every agent folder), those named
    like a registered algorithm first (the paper's five in its order), then the others by name."""
    folders = [folder] if folder is not None else agent_folders()
    names = sorted({p.stem for f in folders if f.is_dir() for p in f.glob("*.toml")})
    first = [a for a in registry.names() if a in names]
    return first + [n for n in names if n not in first]


def where_agents_are() -> str:
    """Where agent files are looked for, and how to add a folder (for an unknown name's error)."""
    folders = ", ".join(map(str, agent_folders()))
    return f"(files in {folders}; NUTRIBENCH_AGENTS=<folder> adds a folder of your own)"


def resolve_agent_path(name_or_path: str | Path) -> Path:
    """A config name (``ppo``: the first agent folder that has ``ppo.toml``; a name in two
    folders with other contents warns which file is used) or a path to a TOML file."""
    import warnings

    s = str(name_or_path)
    if s.endswith(".toml") or "/" in s:
        return resolve_named_file(s, agents_dir(), "agent config", [])
    # a FIFO or a device of that name is found too, and refused in one line when it is read
    found = [f / f"{s}.toml" for f in agent_folders() if (f / f"{s}.toml").exists()]
    if not found:
        raise ConfigError(
            f"unknown agent config '{s}': known are {', '.join(list_agent_configs()) or '(none)'} {where_agents_are()}"
        )
    if len(found) > 1 and read_config_bytes(found[0]) != read_config_bytes(found[1]):  # a copy is no clash
        warnings.warn(f"agent config '{s}': {found[0]} is used, not {found[1]}", stacklevel=2)
    return found[0]


def load_agent_config(name_or_path: str | Path | BaseModel) -> Any:
    """The validated config model of a name, a file, or a model (returned as is)."""
    if isinstance(name_or_path, BaseModel):
        return name_or_path
    path = resolve_agent_path(name_or_path)
    cfg = parse_once(path, lambda data: parse_agent_config(data, path), str(path))  # the models are frozen
    if cfg.name != path.stem:
        raise ConfigError(f"{path}: name: '{cfg.name}' differs from the file name '{path.stem}' (make them equal)")
    return cfg


def agent_config_content(cfg: BaseModel) -> dict[str, Any]:
    """The config as plain data (what is hashed and stored in the database)."""
    return cfg.model_dump(mode="json")


def agent_config_sha256(cfg: BaseModel) -> str:
    """sha256 of the canonical JSON of :func:`agent_config_content`."""
    return content_sha256(agent_config_content(cfg))


#: what of an agent config is no setting: its version and its description (prose)
NOT_SETTINGS = ("version", "description")


def settings_sha256(cfg: BaseModel) -> str:
    """sha256 of a config's settings: :func:`agent_config_content` but :data:`NOT_SETTINGS`
    (two versions of one config that differ in those only hash alike)."""
    return content_sha256({k: v for k, v in agent_config_content(cfg).items() if k not in NOT_SETTINGS})


def body_settings_sha256(body: Any) -> str | None:
    """:func:`settings_sha256` of a stored config body (its content as recorded), read through
    its model (so a value stored as JSON text, ``"inf"``, is the number it names); None for a
    body that does not validate."""
    if not isinstance(body, dict):
        return None
    try:
        return settings_sha256(parse_agent_config(body))
    except (ConfigError, ValueError, TypeError):
        return None


def agent_config_to_toml(cfg: BaseModel) -> str:
    """The config as TOML (round-trips through :func:`load_agent_config`)."""
    data = agent_config_content(cfg)
    data = {"algo": data.pop("algo"), **data}
    return tomli_w.dumps(data)


def parse_agent_config(data: dict[str, Any], source: str | Path = "<dict>") -> Any:
    """Validate plain data as an agent config (one-line :class:`ConfigError` if invalid)."""
    try:
        model = registry.get(data.get("algo")).config_model()  # a list or a table is no name either
    except ConfigError as e:
        raise ConfigError(f"{source}: {e}") from None
    return validate(model, data, source)
