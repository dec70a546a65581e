"""Configuration files as validated, hashed pydantic models."""

from nutribench.config.loading import (
    ConfigError,
    EnvConfig,
    content_sha256,
    list_regimes,
    load_env_config,
    load_model,
    regimes_dir,
)
from nutribench.config.models import NUTRIENTS, FoodCatalog, Regime, RewardConfig

__all__ = [
    "NUTRIENTS",
    "ConfigError",
    "EnvConfig",
    "FoodCatalog",
    "Regime",
    "RewardConfig",
    "content_sha256",
    "list_regimes",
    "load_env_config",
    "load_model",
    "regimes_dir",
]
