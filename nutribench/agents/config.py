"""Agent configurations (the paper's Tables 2-6) as versioned, validated files.

One TOML file per configuration in ``regimes/agents/`` (``<name>.toml``); the ``algo`` key
picks the model (its config model in :mod:`nutribench.agents.registry`), every hyperparameter of the built-in algorithms is written
out (nothing is defaulted), unknown keys are errors, and ``name`` must equal the file name. A
user adds a variant by copying a file, changing ``name`` (and the file name) and the values,
or brings an algorithm of their own: a registered one with its own config model
(:mod:`nutribench.agents.registry`), or ``algo = "external"`` (:class:`ExternalConfig`): an
``entry_point = "package.module:make_agent"`` and a free ``[params]`` table.

The content hash (:func:`agent_config_sha256`) is what the results database records next
to ``name`` and ``version``: a file changed without a version bump is refused by ``run``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import tomli_w
from pydantic import (
    BaseModel,
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    ValidationError,
    model_serializer,
    model_validator,
)

import nutribench.agents.registry as registry
from nutribench.config.loading import (
    ConfigError,
    content_sha256,
    format_validation_error,
    read_toml,
    regimes_dir,
    resolve_named_file,
)

# Every float hyperparameter is finite (inf or nan is refused when the file is read: a learning
# rate of inf trained and was stored as done), but a gradient norm, where inf means no clipping.
PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Prob = Annotated[float, Field(ge=0, le=1, allow_inf_nan=False)]
GradNorm = Annotated[float, Field(gt=0, allow_inf_nan=True, description="inf: no clipping")]
Discount = Annotated[float, Field(gt=0, le=1, allow_inf_nan=False)]
PosInt = Annotated[int, Field(ge=1)]
Name = Annotated[str, Field(pattern=r"^[a-z][a-z0-9_]*$", max_length=64)]
#: a config's version: from 1 to what a database integer holds (the versions are stored in columns)
Version = Annotated[int, Field(ge=1, le=2**31 - 1)]


class _AgentBase(BaseModel):
    """Fields every agent config has."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Name
    version: Version
    description: str
    normalize_obs: bool = Field(description="running mean/std normalisation of observations (SB3 VecNormalize)")
    normalize_reward: bool = Field(
        description="scale rewards by a running std of the discounted return (SB3 VecNormalize); recorded returns stay raw"
    )
    gamma: Discount


class _FeedForward(_AgentBase):
    net_arch: list[PosInt] = Field(min_length=1, description="hidden layers of the shared backbone, e.g. [256, 128]")


class MCConfig(_FeedForward):
    """Monte Carlo actor-critic: one update per complete episode, GAE with lambda = 1."""

    algo: Literal["mc"]
    learning_rate: PosFloat
    gae_lambda: Literal[1.0]
    ent_coef: NonNegFloat
    vf_coef: PosFloat
    max_grad_norm: GradNorm


class _PPOFields(BaseModel):
    """PPO's optimisation fields, shared by the feedforward and the recurrent PPO."""

    learning_rate: PosFloat
    n_steps: PosInt
    batch_size: PosInt
    n_epochs: PosInt
    gae_lambda: Prob
    clip_range: PosFloat
    ent_coef: NonNegFloat
    vf_coef: PosFloat
    max_grad_norm: GradNorm
    normalize_advantage: bool


class PPOConfig(_FeedForward, _PPOFields):
    """PPO, clipped surrogate, shared actor-critic."""

    algo: Literal["ppo"]


class GRUPPOConfig(_AgentBase, _PPOFields):
    """PPO with the recurrent two-GRU policy of the paper's Table 6 (heads fixed by the paper)."""

    algo: Literal["gru_ppo"]
    hidden_size: PosInt
    sequence_length: PosInt
    memory: bool = Field(
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


class DDQNConfig(_FeedForward):
    """Double DQN with n-step returns."""

    algo: Literal["ddqn"]
    learning_rate_start: PosFloat
    learning_rate_end: PosFloat
    buffer_size: PosInt
    learning_starts: Annotated[int, Field(ge=0)]
    batch_size: PosInt
    n_step: PosInt
    max_grad_norm: GradNorm
    target_update_interval: PosInt
    train_freq: PosInt
    gradient_steps: PosInt
    exploration_initial_eps: Prob
    exploration_final_eps: Prob
    exploration_fraction: Prob


class SACConfig(_FeedForward):
    """Discrete-action SAC, fixed temperature."""

    algo: Literal["sac"]
    actor_learning_rate: PosFloat
    critic_learning_rate: PosFloat
    buffer_size: PosInt
    learning_starts: Annotated[int, Field(ge=0)]
    batch_size: PosInt
    tau: Prob
    alpha: NonNegFloat
    train_freq: PosInt
    gradient_steps: PosInt


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
    normalize_obs: bool = Field(default=False, description="wrap the env in VecNormalize(norm_obs=True)")
    normalize_reward: bool = Field(default=False, description="wrap the env in VecNormalize(norm_reward=True)")
    gamma: Discount = Field(default=0.99, description="VecNormalize's return discount")


def agents_dir() -> Path:
    """``regimes/agents/`` (or ``$NUTRIBENCH_AGENTS``)."""
    import os

    env = os.environ.get("NUTRIBENCH_AGENTS")
    return Path(env) if env else regimes_dir() / "agents"


def list_agent_configs(folder: Path | None = None) -> list[str]:
    """Names of the agent config files, those named like a registered algorithm first (the
    paper's five in its order), then the others by name."""
    folder = folder or agents_dir()
    names = sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []
    first = [a for a in registry.names() if a in names]
    return first + [n for n in names if n not in first]


def resolve_agent_path(name_or_path: str | Path) -> Path:
    """A config name (``ppo``) or a path to a TOML file."""
    return resolve_named_file(name_or_path, agents_dir(), "agent config", list_agent_configs())


def load_agent_config(name_or_path: str | Path | BaseModel) -> Any:
    """The validated config model of a name, a file, or a model (returned as is)."""
    if isinstance(name_or_path, BaseModel):
        return name_or_path
    path = resolve_agent_path(name_or_path)
    cfg = parse_agent_config(read_toml(path), path)
    if cfg.name != path.stem:
        raise ConfigError(f"{path}: name: '{cfg.name}' differs from the file name '{path.stem}' (make them equal)")
    return cfg


def agent_config_content(cfg: BaseModel) -> dict[str, Any]:
    """The config as plain data (what is hashed and stored in the database)."""
    return cfg.model_dump(mode="json")


def agent_config_sha256(cfg: BaseModel) -> str:
    """sha256 of the canonical JSON of :func:`agent_config_content`."""
    return content_sha256(agent_config_content(cfg))


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
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(source, e)) from None
