"""Loading, validating and hashing the environment's configuration files.

Every failure raises :class:`ConfigError` with one line that names the file and the field,
so the CLI can print it and exit non-zero without a traceback.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property, partialmethod
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
from pydantic import BaseModel, ValidationError

from nutribench.config.models import FoodCatalog, Regime, RewardConfig
from nutribench.config.reading import ConfigError, parse_config, read_config_bytes
from nutribench.config.sizes import dynamics_bytes, too_large
from nutribench.safe_write import file_kind

M = TypeVar("M", bound=BaseModel)
T = TypeVar("T")

#: A regime's observation options, in ladder order; each enters its content hash only when on.
OBSERVATION_OPTIONS = ("observe_clock", "observe_pending", "observe_latent")


def regimes_dir() -> Path:
    """Where the regime files live.

    ``$NUTRIBENCH_REGIMES`` if set; else the ``regimes/`` folder of the source checkout
    (editable install); else the copy shipped inside the wheel.
    """
    env = os.environ.get("NUTRIBENCH_REGIMES")
    if env:
        check_folder_setting("NUTRIBENCH_REGIMES", Path(env), "the folder of the regime files")
        return Path(env)
    package = Path(__file__).resolve().parents[1]
    for candidate in (package.parent / "regimes", package / "_regimes"):
        if candidate.is_dir():
            return candidate
    raise ConfigError("no regimes folder found: set NUTRIBENCH_REGIMES to the folder holding run0.toml .. run6.toml")


def check_folder_setting(variable: str, folder: Path, what: str) -> None:
    """A folder named by an environment variable that is there but is no folder (a file, a
    FIFO, a device node) is a one-line :class:`ConfigError`, never silently a folder without
    files; one that is not there yet is left to its readers (and writers)."""
    try:
        mode = os.stat(folder).st_mode
    except (FileNotFoundError, NotADirectoryError):
        return
    except OSError as e:
        raise ConfigError(f"{variable}={folder}: cannot look at it: {e.strerror or e}") from None
    if not stat.S_ISDIR(mode):
        raise ConfigError(f"{variable}={folder}: is {file_kind(mode)}, not a folder: set {variable} to {what}")


def format_validation_error(path: Path | str, err: ValidationError) -> str:
    """One line: file, the first failing field and what is wrong (and how many more)."""
    errors = err.errors()
    first = errors[0]
    msg = first["msg"].removeprefix("Value error, ")  # a validator's own words
    if first["type"] == "extra_forbidden":
        msg = "unknown key (remove it or check its spelling)"
    elif first["type"] == "missing":
        msg = "missing (every value must be written out; nothing is defaulted)"
    elif "input" in first and not isinstance(first["input"], (dict, list)):
        msg = f"{msg} (got {first['input']!r})"
    more = f" (+{len(errors) - 1} more errors)" if len(errors) > 1 else ""
    where = f"{'.'.join(map(str, first['loc']))}: " if first["loc"] else ""  # a check of several fields names them
    return f"{path}: {where}{msg}{more}"


def read_toml(path: Path) -> dict[str, Any]:
    """The TOML file at ``path`` as a dict, read as :mod:`nutribench.config.reading` bounds it:
    a missing or unreadable file, one that is not a regular file (a FIFO, a device), one too
    large or nested too deep, a byte that is not UTF-8, malformed TOML and a control character
    in a string are each a one-line :class:`ConfigError` naming the file (and the line or key)."""
    return parse_config(path, read_config_bytes(path))


def resolve_named_file(name_or_path: str | Path, folder: Path, what: str, known: list[str]) -> Path:
    """A file named by ``name`` (``folder/<name>.toml``) or given as a path to a TOML file;
    a one-line :class:`ConfigError` naming ``what`` (e.g. "agent config") and the ``known``
    names when it is not there."""
    s = str(name_or_path)
    if s.endswith(".toml") or "/" in s:
        path = Path(s)
        if not path.exists():
            raise ConfigError(f"{path}: no such {what} file")
        return path  # not a regular file (a FIFO, a folder): refused in one line when read
    path = folder / f"{s}.toml"
    if not path.exists():
        raise ConfigError(f"unknown {what} '{s}': known are {', '.join(known) or '(none)'} (files in {folder})")
    return path


#: what was parsed from each file: (a tag, the file's content digest) -> the parsed object (frozen)
_PARSED: dict[tuple[Any, bytes], Any] = {}


def parse_once(path: Path, parse: Callable[[dict[str, Any]], T], tag: Any) -> T:
    """``parse`` of the TOML file at ``path`` (:func:`read_toml`), once per content and ``tag``
    in this process (what it returns must be frozen): a tuning study loaded its regime files
    thousands of times (issue 51); reading the bytes is cheap. The key is a digest of the
    file's bytes: a file changed in any way (even within one tick of the file system's clock,
    its size kept) is parsed again; one that cannot be read raises :func:`read_toml`'s line."""
    key = (tag, hashlib.blake2b(read_config_bytes(path), digest_size=20).digest())
    if key not in _PARSED:
        _PARSED[key] = parse(read_toml(path))
    return _PARSED[key]


def validate(model: type[M], data: Any, source: Path | str) -> M:
    """``data`` validated as ``model``, its validation errors one-line ConfigErrors naming ``source``."""
    try:
        return model.model_validate(data)
    except ValidationError as e:
        raise ConfigError(format_validation_error(source, e)) from None


def load_model(model: type[M], path: Path) -> M:
    """Read a TOML file into ``model``, turning validation errors into one-line ConfigErrors.

    Each content is parsed and validated once per process (the models are frozen:
    :func:`parse_once`)."""
    return parse_once(path, lambda data: validate(model, data, path), model)


def content_sha256(obj: Any) -> str:
    """The hash of a config's content as stable JSON text (key order and formatting do not matter)."""
    return hashlib.sha256(json.dumps(obj, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


@dataclass(frozen=True)
class EnvConfig:
    """Everything that fixes the dynamics of one regime: regime + food catalog + reward.

    ``sha256`` hashes the semantic content of all three (not the file formatting), so a
    result row can be traced to the exact dynamics that made it. The regime's observation
    options (``observe_clock``, ``observe_pending``, ``observe_latent``) enter the content
    only when they are on, so a regime without them hashes as it did before they existed.
    """

    regime: Regime
    catalog: FoodCatalog
    reward: RewardConfig
    path: Path | None = None

    def __post_init__(self) -> None:
        where = self.path or f"regime {self.regime.name}"
        cat, reg = set(self.catalog.keys), set(self.regime.foods)
        if cat != reg:
            parts = [f"no delays for catalog foods {sorted(cat - reg)}"] if cat - reg else []
            parts += [f"delays for foods not in the catalog {sorted(reg - cat)}"] if reg - cat else []
            raise ConfigError(
                f"{where}: foods: catalog size mismatch: the regime has {len(reg)} foods, "
                f"the catalog '{self.regime.catalog}' has {len(cat)}; " + "; ".join(parts)
            )
        horizon, level = self.reward.horizon, self.regime.observation_level
        why = too_large(
            f"a horizon of {horizon:,} steps (reward.horizon, {self.regime.reward}) with {len(cat):,} foods "
            f"(the catalog {self.regime.catalog}) at observation level {level}: the regime's dynamics",
            dynamics_bytes(len(cat), horizon, level),
        )
        if why:
            raise ConfigError(f"{where}: {why}")

    @property
    def name(self) -> str:
        return self.regime.name

    @property
    def version(self) -> int:
        return self.regime.version

    def content(self) -> dict[str, Any]:
        return {
            # the observation options (a regime's only defaults) only when on
            "regime": self.regime.model_dump(mode="json", exclude_defaults=True),
            "catalog": self.catalog.model_dump(mode="json"),
            "reward": self.reward.model_dump(mode="json"),
        }

    @cached_property
    def sha256(self) -> str:
        return content_sha256(self.content())

    # ---- arrays the environment uses (catalog order, nutrients C, F, P) ----
    def masses(self) -> np.ndarray:
        return self.catalog.masses()

    def _delay_array(self, what: str) -> np.ndarray:
        return np.stack([getattr(self.regime.foods[key], what).as_array() for key in self.catalog.keys])

    tau = partialmethod(_delay_array, "tau")
    sigma = partialmethod(_delay_array, "sigma")


def resolve_regime_path(regime: str | os.PathLike[str]) -> Path:
    """A regime name (``run3``) or a path to a regime file."""
    s = str(regime)
    if s.endswith(".toml") or os.sep in s or "/" in s:
        return Path(s)
    path = regimes_dir() / f"{s}.toml"
    if not path.exists():
        known = ", ".join(list_regimes()) or "none"
        raise ConfigError(f"unknown regime '{s}': known regimes are {known} (or give a path to a .toml file)")
    return path


def load_env_config(regime: str | os.PathLike[str] | EnvConfig) -> EnvConfig:
    """Load a regime by name, path, or pass an :class:`EnvConfig` through."""
    if isinstance(regime, EnvConfig):
        return regime
    path = resolve_regime_path(regime)
    reg = load_model(Regime, path)
    if reg.name != path.stem:  # results are stored under the name, and regime=NAME finds the file by it
        raise ConfigError(
            f"{path}: name = \"{reg.name}\" differs from the file name '{path.stem}': "
            f'set name = "{path.stem}" or rename the file to {reg.name}.toml'
        )
    catalog = load_model(FoodCatalog, path.parent / reg.catalog)
    reward = load_model(RewardConfig, path.parent / reg.reward)
    return EnvConfig(regime=reg, catalog=catalog, reward=reward, path=path)


def list_regimes(folder: Path | None = None) -> list[str]:
    """Names of the regime files in ``folder``: files with any of a regime's own keys
    (``ranges``, ``foods``, ``catalog``), so that a regime file missing one of them is listed
    and then fails to load with the field named. A file that is not valid TOML raises
    :class:`ConfigError` (file, line and column): it must not silently leave the grid."""
    folder = folder or regimes_dir()
    return [p.stem for p in sorted(folder.glob("*.toml")) if {"ranges", "foods", "catalog"} & read_toml(p).keys()]
