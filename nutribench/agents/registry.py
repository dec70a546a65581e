"""ONE registry of algorithms: an agent config's ``algo`` -> how to build its model and how to
load a saved one.

The five built-in algorithms are registered the way a plug-in is, by entry point strings
(``"package.module:attribute"``, as Gymnasium's ``entry_point``), so nothing below this
registry treats a sixth agent as a special case::

    algo = "external"
    entry_point = "examples.recurrent_ppo:make_agent"   # make_agent(params, env, seed)
    [params]
    n_steps = 500

An external config's builder is its ``entry_point``; by convention its loader is the ``load``
function of the same module (``load(path)`` returns the saved model), noted in a saved model's
sidecar but imported only when the user names it (``TrainedAgent.load(path, load_with=...)``,
``nutribench evaluate --entry-point``): a model file never chooses the code that loads it.
Entry points are imported by name, in each worker, from installed packages or from the
current folder (as ``python -m`` does).
"""

from __future__ import annotations

import copy
import importlib
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nutribench.config.loading import ConfigError
from nutribench.provenance import file_sha256


@dataclass(frozen=True)
class Algorithm:
    """One registered algorithm.

    :param algo: the ``algo`` key of its config files.
    :param build: entry point of ``f(cfg, env, seed, horizon) -> model`` (None: the config's
        own ``entry_point``, called as ``make_agent(params, env, seed)``).
    :param load: entry point of what loads a saved model: a class with ``.load(path)`` or a
        function ``load(path)`` (None: ``load`` beside the config's entry point).
    :param plain: the class that loads the saved ``.zip`` with plain SB3 (no nutribench code
        path), written into the model's sidecar for users of other tools.
    """

    algo: str
    build: str | None
    load: str | None
    plain: str | None = None


_BUILD = "nutribench.agents.algos:build_model"
ALGORITHMS: dict[str, Algorithm] = {
    a.algo: a
    for a in (
        # MC, DDQN and PPO are SB3's A2C, DQN and PPO with other settings, another train() or
        # a logged gradient norm: plain SB3 loads and acts with them; discrete SAC and GRU-PPO
        # have policies of their own
        Algorithm("mc", _BUILD, "nutribench.agents.algos:MonteCarloAC", "stable_baselines3.A2C"),
        Algorithm("ddqn", _BUILD, "nutribench.agents.algos:DoubleDQN", "stable_baselines3.DQN"),
        Algorithm("ppo", _BUILD, "nutribench.agents.algos:PPOWithGradNorm", "stable_baselines3.PPO"),
        Algorithm("sac", _BUILD, "nutribench.agents.sac:DiscreteSAC", "nutribench.agents.sac.DiscreteSAC"),
        Algorithm("gru_ppo", _BUILD, "nutribench.agents.gru_ppo:GRUPPO", "nutribench.agents.gru_ppo.GRUPPO"),
        Algorithm("external", None, None),
    )
}


class EntryPointError(ConfigError):
    """An entry point that cannot be imported or lacks its attribute (one line)."""


def import_entry_point(entry_point: str) -> Any:
    """The object ``package.module:attribute`` names; the current folder is searched too."""
    module_name, _, attr = entry_point.partition(":")
    if not attr:
        raise EntryPointError(f"entry point {entry_point!r}: write it as package.module:attribute")
    try:
        module = _import(module_name)
    except ImportError as e:
        raise EntryPointError(
            f"entry point {entry_point!r}: cannot import {module_name} ({e}): install its package or run from the folder holding it"
        ) from None
    try:
        return getattr(module, attr)
    except AttributeError:
        raise EntryPointError(f"entry point {entry_point!r}: module {module_name} has no attribute {attr!r}") from None


def _import(module_name: str) -> Any:
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        cwd = str(Path.cwd())
        if cwd in sys.path or not (e.name and module_name.startswith(e.name)):
            raise
        sys.path.append(cwd)  # a module beside the user's scripts, as `python -m` finds it
        return importlib.import_module(module_name)


def entry_point_source(entry_point: str) -> tuple[str, str | None]:
    """``(entry point, sha256 of its module's file)``: what an external job records."""
    module = _import(entry_point.partition(":")[0])
    path = getattr(module, "__file__", None)
    return entry_point, file_sha256(path)


def algorithm(cfg: Any) -> Algorithm:
    """The registry entry of an agent config."""
    return ALGORITHMS[cfg.algo]


def loader_entry_point(cfg: Any) -> str:
    """What loads this config's saved model (written into the model's ``.json`` sidecar as a
    note for plain SB3 and the user; ``TrainedAgent.load`` never imports it from there)."""
    entry = algorithm(cfg)
    if entry.load is not None:
        return entry.load
    if not cfg.entry_point:
        raise ConfigError(f"agent config {cfg.name}: no entry_point, so nothing can load its model")
    return cfg.entry_point.partition(":")[0] + ":load"


def make_model(cfg: Any, env: Any, seed: int, horizon: int) -> Any:
    """The algorithm object of ``cfg`` on ``env`` (a built-in's builder, or a plug-in's
    ``make_agent(params, env, seed)``)."""
    entry = algorithm(cfg)
    if entry.build is not None:
        return import_entry_point(entry.build)(cfg, env, seed=seed, horizon=horizon)
    if not cfg.entry_point:
        raise ConfigError(
            f"agent config {cfg.name}: algo 'external' without entry_point can only hold recorded results; "
            'add entry_point = "package.module:make_agent" to train it'
        )
    # a deep copy: SB3 classes write into nested params (QRDQN puts th.optim.Adam into
    # policy_kwargs), which must never reach the config the job stores
    model = import_entry_point(cfg.entry_point)(copy.deepcopy(dict(cfg.params)), env, seed)
    for method in ("learn", "predict", "save"):
        if not callable(getattr(model, method, None)):
            raise ConfigError(
                f"{cfg.entry_point} returned a {type(model).__name__} without {method}(): it needs SB3's learn, predict and save"
            )
    return model


def load_model(load_with: str, path: str | Path) -> Any:
    """A saved model, loaded by ``load_with`` (a class with ``.load`` or a function)."""
    obj = import_entry_point(load_with)
    if isinstance(obj, type):
        from stable_baselines3.common.base_class import BaseAlgorithm

        return obj.load(path, device="cpu") if issubclass(obj, BaseAlgorithm) else obj.load(path)
    return obj(path)
