"""Search spaces: which hyperparameters of an agent a tuning study varies, over which ranges.

One versioned TOML file per space in ``regimes/search/`` (``<name>.toml``, or
``$NUTRIBENCH_REGIMES/search``), validated like the agent files (unknown keys are errors,
``name`` equals the file name, a content hash is recorded with the study)::

    name = "ppo"
    version = 1
    agent = "ppo"              # the agent file every trial starts from
    description = "..."

    [params.learning_rate]
    kind = "float"             # float | int | categorical
    low = 1e-5
    high = 2e-3
    log = true                 # sampled uniformly in log space
    why = "rl-zoo3's sample_ppo_params: log-uniform 1e-5 .. 2e-3"

    [params.n_epochs]
    kind = "categorical"
    choices = [5, 10, 20]
    why = "..."

    [kept]                     # a hyperparameter another agent's space searches, kept here
    gae_lambda = "lambda = 1 is what makes MC Monte Carlo"

Every searched name must be a hyperparameter of the base agent's config model (for a plug-in,
``algo = "external"``, a key of its ``[params]`` table), and every range's ends and every
choice must make a valid agent config (checked when the file is loaded, so a study never
starts on a range it would fail in). Whatever the space does not name keeps the base file's
value. Categorical choices may be lists (``net_arch``); Optuna sees them as their JSON text.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from nutribench.agents.config import Name, load_agent_config, parse_agent_config
from nutribench.agents.registry import by_entry_point
from nutribench.config.loading import ConfigError, content_sha256, read_toml, regimes_dir, resolve_named_file, validate
from nutribench.config.sizes import size

#: the fields of an agent config that name or describe it, never searched
_IDENTITY = ("algo", "name", "version", "description", "entry_point")

Scalar = bool | int | float | str


class Param(BaseModel):
    """One searched hyperparameter: a float or int range (``low``..``high``, ``log``) or ``choices``."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["float", "int", "categorical"]
    low: float | None = None
    high: float | None = None
    log: bool = False
    choices: list[Scalar | list[Scalar]] | None = Field(default=None, min_length=1)
    why: str = Field(min_length=1, description="where the range comes from (a source, a measurement)")

    @model_validator(mode="after")
    def _shape(self) -> Param:
        if self.kind == "categorical":
            if self.choices is None or self.low is not None or self.high is not None:
                raise ValueError("a categorical parameter has choices = [...] and no low/high")
            return self
        if self.choices is not None or self.low is None or self.high is None:
            raise ValueError(f"a {self.kind} parameter has low and high and no choices")
        if not (math.isfinite(self.low) and math.isfinite(self.high)) or self.low >= self.high:
            raise ValueError(f"low ({self.low}) must be below high ({self.high}), both finite")
        if self.log and self.low <= 0:
            raise ValueError(f"log = true needs low > 0 (low = {self.low})")
        if self.kind == "int" and (self.low != int(self.low) or self.high != int(self.high)):
            raise ValueError("an int parameter's low and high are whole numbers")
        return self

    def ends(self) -> list[Any]:
        """The values that bound the range: low and high, or every choice."""
        if self.kind == "categorical":
            return list(self.choices or [])
        if self.kind == "int":
            return [int(self.low), int(self.high)]  # type: ignore[arg-type]
        return [self.low, self.high]

    def suggest(self, trial: Any, name: str) -> Any:
        """Draw this parameter for an Optuna ``trial``."""
        if self.kind == "float":
            return trial.suggest_float(name, self.low, self.high, log=self.log)
        if self.kind == "int":
            return trial.suggest_int(name, int(self.low), int(self.high), log=self.log)  # type: ignore[arg-type]
        encoded = [json.dumps(c) if isinstance(c, list) else c for c in self.choices or []]
        return decoded(trial.suggest_categorical(name, encoded))


def decoded(value: Any) -> Any:
    """A value as Optuna stores it back as the agent file wants it (a list choice from its JSON text)."""
    return json.loads(value) if isinstance(value, str) and value.startswith("[") else value


class SearchSpace(BaseModel):
    """A tuning study's search space (the module docstring shows the file)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: Name
    version: Annotated[int, Field(ge=1)]
    agent: str = Field(min_length=1, description="the agent file (name or path) trials start from")
    description: str
    params: dict[Name, Param] = Field(min_length=1)
    kept: dict[Name, str] = Field(
        default_factory=dict,
        description="hyperparameters another agent's space searches that this one keeps at its base value, and why",
    )

    @property
    def sha256(self) -> str:
        """Content hash of the space (recorded with the study; a space without ``kept`` hashes
        as before the field existed, so its studies resume)."""
        data = self.model_dump(mode="json")
        if not data["kept"]:
            del data["kept"]
        return content_sha256(data)

    def base(self) -> Any:
        """The validated base agent config."""
        return load_agent_config(self.agent)

    def suggest(self, trial: Any) -> dict[str, Any]:
        """One trial's values of every searched parameter."""
        return {name: p.suggest(trial, name) for name, p in self.params.items()}

    def config(self, values: dict[str, Any], *, name: str | None = None, description: str | None = None) -> Any:
        """The agent config of ``values`` (the base file's, the searched ones replaced), validated;
        under a new ``name`` it is that new file's version 1."""
        data = self.base().model_dump(mode="json")
        hyperparameters(data).update(values)
        if name is not None and name != data["name"]:
            data["name"], data["version"] = name, 1
        data["description"] = description or data["description"]
        return parse_agent_config(data, f"search space {self.name!r}")


def hyperparameters(data: dict[str, Any]) -> dict[str, Any]:
    """The hyperparameters in an agent config's JSON dump ``data`` (the same dict, to read or
    update): a plug-in's ``[params]`` table (``algo = "external"``), else the config's own keys."""
    return data["params"] if by_entry_point(data["algo"]) else data


def resolve_space_path(name_or_path: str | Path) -> Path:
    """A space name (``ppo``: a file of ``regimes/search/``, under ``$NUTRIBENCH_REGIMES`` when
    set) or a path to a TOML file."""
    folder = regimes_dir() / "search"
    known = sorted(p.stem for p in folder.glob("*.toml")) if folder.is_dir() else []
    return resolve_named_file(name_or_path, folder, "search space", known)


def load_search_space(name_or_path: str | Path) -> SearchSpace:
    """The validated search space of a name or file: its keys, its parameters against the base
    agent's config model, and each range's ends as valid configs (one-line :class:`ConfigError`)."""
    path = resolve_space_path(name_or_path)
    return validated_space(read_toml(path), path, path.stem)


def validated_space(data: dict[str, Any], source: Path | str, file_name: str | None = None) -> SearchSpace:
    """The search space of ``data`` (a space file's table), validated as :func:`load_search_space`
    says; ``source`` names it in the one-line :class:`ConfigError`, whose ``name`` must be
    ``file_name`` where one is given."""
    space = validate(SearchSpace, data, source)
    if file_name is not None and space.name != file_name:
        raise ConfigError(f"{source}: name: '{space.name}' differs from the file name '{file_name}' (make them equal)")
    check_space(space, source)
    return space


def check_space(space: SearchSpace, source: Path | str) -> None:
    """Every searched name is a hyperparameter of the base agent, and every end of every range
    gives a valid config (the other parameters at the base file's values)."""
    try:
        base = space.base()
    except ConfigError as e:
        raise ConfigError(f"{source}: agent: {e}") from None
    data = base.model_dump(mode="json")
    plugin = by_entry_point(data["algo"])
    known = set(data["params"]) if plugin else set(data) - set(_IDENTITY)
    for name in space.kept:
        if name not in known or name in space.params:
            raise ConfigError(
                f"{source}: kept.{name}: not a hyperparameter of agent {base.name!r} it keeps"
                + (" (it is searched in [params])" if name in space.params else "")
            )
    for name, param in space.params.items():
        if name not in known:
            names = ", ".join(sorted(known))
            where = f"keys of its [params]: {names or '(none)'}" if plugin else f"its hyperparameters: {names}"
            raise ConfigError(f"{source}: params.{name}: not a hyperparameter of agent {base.name!r} ({where})")
        for value in param.ends():
            try:
                space.config({name: value})
            except ConfigError as e:
                raise ConfigError(
                    f"{source}: params.{name}: the value {value!r} gives no valid agent config: {e}"
                ) from None


#: floats per observation the memory estimate assumes: the environments observe tens of
#: floats; a generous bound, so that the estimate errs high
OBS_FLOATS = 256
#: copies of a network's parameters a trial holds: weights, gradients, two Adam moments, for up to
#: five networks (SAC: actor, two critics and their targets)
_PARAM_COPIES = 4 * 5


def estimate_bytes(values: dict[str, Any], agents: int) -> int:
    """A rough upper estimate of the memory ``agents`` agents of the hyperparameters ``values``
    need: their networks (``net_arch``, a GRU's ``hidden_size``) with gradients and optimiser
    state, and their rollout buffers (``n_steps`` steps of observations and a GRU's states)."""
    arch = values.get("net_arch")
    widths = [OBS_FLOATS, *[int(w) for w in arch]] if isinstance(arch, list) else [OBS_FLOATS, 64]
    hidden = int(values.get("hidden_size", 0) or 0)
    params = sum(a * b + b for a, b in zip(widths, widths[1:])) + 3 * (
        widths[-1] * hidden + hidden * hidden + 2 * hidden
    )
    params += (hidden or widths[-1]) * 8  # the heads
    steps = int(values.get("n_steps", 1) or 1)
    rollout = steps * (OBS_FLOATS + 8 + hidden)
    return agents * 4 * (params * _PARAM_COPIES + rollout)


def check_space_memory(space: SearchSpace, agents: int, limit: int | None = None) -> None:
    """Refuse in one line a space whose largest trial (each parameter at the end of its range
    that needs the most memory, the others at the base file's values) would need more memory
    than this machine has (:func:`estimate_bytes`: its networks and rollout buffers), before a
    study is opened: such a trial would fail with a MemoryError and be left failed in it."""
    if limit is None:
        try:  # this machine's memory
            limit = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (ValueError, OSError, AttributeError):  # the system does not say
            return
    base = hyperparameters(space.base().model_dump(mode="json"))
    worst = dict(base)
    for name, param in space.params.items():
        worst[name] = max(param.ends(), key=lambda v, n=name: estimate_bytes({**base, n: v}, agents))
    need = estimate_bytes(worst, agents)
    if need > limit:
        shown = ", ".join(
            f"{k} {worst[k]}" for k in ("net_arch", "hidden_size", "n_steps") if k in space.params and k in worst
        )
        raise ConfigError(
            f"search space {space.name!r}: its largest trial ({shown or 'the base values'}, {agents} agents) would "
            f"need about {size(need)} of memory, more than this machine's {size(limit)}: narrow its ranges"
        )
