"""THE registry of algorithms: everything nutribench knows about one algorithm, in one entry.

An :class:`Algorithm` says, for the ``algo`` key of its agent config files: the config model
(pydantic, validated when a file is read), how to build its model and load a saved one, the
plain SB3 class its models load with, its label and colour in figures, its batched class in
:mod:`nutribench.engine` (optional) and what of it the batched engine cannot train. Nothing
but an algorithm's own module spells out its name, this registry included: every other module
asks the registry (tests/test_algorithm_registry.py greps for names).

Adding a built-in is one new module of :data:`BUILTIN_PACKAGE` (``nutribench/agents/builtin/``),
named like its ``algo``: its config model, its arguments function, its SB3 class and its entry
``ALGORITHM = Algorithm(...)``. :func:`builtin_algorithms` finds the entries by scanning that
package, and lists them by ``order`` (the paper's), ``external`` last; nothing else is touched.

Adding a plug-in is one installed package: an entry of the entry-point group
``nutribench.algorithms`` names its :class:`Algorithm` object (as Gymnasium's ``register``)::

    [project.entry-points."nutribench.algorithms"]
    a2c = "my_package.algo:A2C_ALGORITHM"     # an Algorithm(...) object

nutribench's own pyproject.toml lists no built-in there: they are read from the package, so
they are there when the installed metadata is stale or absent (an editable install of another
checkout, a source tree on ``PYTHONPATH``), and entries of the group that point into
nutribench itself are skipped. :func:`register` adds one in-process (tests, notebooks).

Besides, ``algo = "external"`` keeps a plug-in without a package: an ``entry_point =
"package.module:make_agent"`` and a free ``[params]`` table. Its builder is that entry point;
by convention its loader is the ``load`` function of the same module (``load(path)`` returns
the saved model), noted in a saved model's sidecar but imported only when the user names it
(``TrainedAgent.load(path, load_with=...)``, ``nutribench evaluate --entry-point``): a model
file never chooses the code that loads it. Entry points are imported by name, in each worker,
from installed packages or from the current folder (as ``python -m`` does).
"""

from __future__ import annotations

import copy
import functools
import importlib
import math
import pkgutil
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeAlias

from nutribench.config.loading import ConfigError
from nutribench.provenance import file_sha256

if TYPE_CHECKING:
    from stable_baselines3.common.base_class import BaseAlgorithm

#: the entry-point group algorithms register in
ENTRY_POINT_GROUP = "nutribench.algorithms"
#: the package of the built-in algorithms, one module each holding its ``ALGORITHM``
BUILTIN_PACKAGE = "nutribench.agents.builtin"
#: what builds a model for an algorithm whose ``arguments`` are given (SB3 classes)
SB3_BUILD = "nutribench.agents.algos:build_model"
#: what an algorithm's ``arguments`` function returns: the SB3 class and its constructor
#: arguments but env, seed, device, verbose and gamma (what :data:`SB3_BUILD` adds)
ModelArguments: TypeAlias = "tuple[type[BaseAlgorithm], dict[str, Any]]"


@dataclass(frozen=True)
class Algorithm:
    """One registered algorithm.

    :param algo: the ``algo`` key of its config files.
    :param config: its config model (a pydantic model class, or ``"package.module:Class"``);
        it has ``algo: Literal["<algo>"]``, ``name``, ``version``, ``description``,
        ``normalize_obs``, ``normalize_reward`` and ``gamma`` (what every job reads).
    :param build: entry point of ``f(cfg, env, seed, horizon) -> model`` (default
        :data:`SB3_BUILD`, which needs ``arguments``); None: the config's own ``entry_point``,
        called as ``make_agent(params, env, seed)`` (``algo = "external"``).
    :param arguments: entry point of ``f(cfg, horizon) -> (SB3 class, constructor arguments
        but env, seed, device, verbose and gamma)``, what :data:`SB3_BUILD` builds from.
    :param load: entry point of what loads a saved model: a class with ``.load(path)`` or a
        function ``load(path)`` (None: ``load`` beside the config's entry point).
    :param plain: the class that loads the saved ``.zip`` with plain SB3 (no nutribench code
        path), written into the model's sidecar for users of other tools (None: ``load``).
    :param label: its label in figures and tables (default: ``algo``); the config file named
        like the algorithm is drawn under it.
    :param color: its colour in figures (None: one derived from the name, as for any config).
    :param order: where a built-in stands in every list of algorithms (the paper's order: MC 1,
        DDQN 2, PPO 3, SAC 4, GRU-PPO 5; unset: after those, by name).
    :param batched: ``"package.module:Class"`` of its class in the batched engine
        (a :class:`nutribench.engine.algorithm.BatchedAlgorithm`), None if it has none.
    :param batch_limits: ``f(cfg, horizon) -> reason or None``: what of a config the batched
        class does not train as the SB3 one does (``horizon`` may be None: unknown); the
        reason names the setting and the fix (the caller adds the config's name).
    :param cost: relative cost of a training day against PPO's, for ordering long jobs first.
    :param bench_days: the learning benchmark's default budget (None: its ``DEFAULT_BUDGET``).
    :param bare: the throughput benchmark's plain-SB3 references, ``(entry point of a class
        built with the same arguments, label)``; the first is what the plumbing is timed against.
    """

    algo: str
    config: type | str
    build: str | None = SB3_BUILD
    arguments: str | None = None
    load: str | None = None
    plain: str | None = None
    label: str | None = None
    color: str | None = None
    order: float = math.inf
    batched: str | None = None
    batch_limits: Callable[[Any, int | None], str | None] | None = field(default=None, compare=False)
    cost: float = 1.0
    bench_days: int | None = None
    bare: tuple[tuple[str, str], ...] = ()

    def config_model(self) -> type:
        """The config model class."""
        return import_entry_point(self.config) if isinstance(self.config, str) else self.config

    @property
    def display(self) -> str:
        """Its label (``algo`` when none is given)."""
        return self.label or self.algo


def no_replay_scaling(cfg: Any, horizon: int | None) -> str | None:
    """``batch_limits`` of an off-policy algorithm: its batched replay would have to scale
    sampled rewards."""
    why = "the batched engine does not scale replayed rewards (normalize_reward = true); set normalize_reward = false"
    return why if cfg.normalize_reward else None


_EXTRA: dict[str, Algorithm] = {}


class AlgorithmRegistryError(ConfigError):
    """An algorithm that cannot be registered: a taken name, an entry point that is no
    :class:`Algorithm` (one line)."""


@functools.cache
def _builtin_modules() -> tuple[Any, ...]:
    """The modules of :data:`BUILTIN_PACKAGE` (imported now), but those named ``_...``."""
    package = importlib.import_module(BUILTIN_PACKAGE)
    found = pkgutil.iter_modules(package.__path__)
    return tuple(importlib.import_module(f"{BUILTIN_PACKAGE}.{m.name}") for m in found if not m.name.startswith("_"))


@functools.cache
def builtin_algorithms() -> tuple[Algorithm, ...]:
    """The built-in algorithms: the ``ALGORITHM`` of each module of :data:`BUILTIN_PACKAGE`, by
    ``order`` (the paper's), then by name; those without a builder (``external``) last."""
    out: dict[str, Algorithm] = {}
    for module in _builtin_modules():
        entry = getattr(module, "ALGORITHM", None)
        if not isinstance(entry, Algorithm) or entry.algo in out:
            raise AlgorithmRegistryError(
                f"{module.__name__}: a built-in algorithm's module must define ALGORITHM = Algorithm(...) "
                "with an algo of its own (a module of shared pieces: name it _...)"
            )
        out[entry.algo] = entry
    return tuple(sorted(out.values(), key=lambda a: (a.build is None, a.order, a.algo)))


def builtin_attribute(module: str, name: str) -> Any:
    """What ``module`` answers for a name it lacks (its ``__getattr__``): the attribute ``name``
    of the one built-in module that has it. :mod:`nutribench.agents.config` and
    :mod:`nutribench.agents.algos`, which held the built-ins before each was one module, still
    answer their names so (``nutribench.agents.config.MCConfig``)."""
    holders = [m for m in _builtin_modules() if hasattr(m, name)] if not name.startswith("_") else []
    if len(holders) != 1:
        raise AttributeError(f"module {module!r} has no attribute {name!r}")
    return getattr(holders[0], name)


def lazy_attributes(module: str, /, **homes: str) -> Callable[[str], Any]:
    """A ``__getattr__`` for ``module`` that answers each name of ``homes`` with that of the
    module it maps to, imported when the name is first asked for. A built-in's module keeps its
    SB3 class elsewhere (torch and Stable-Baselines3 load with it) and still answers its name, so
    that reading an agent config, as every command does before it starts, imports neither."""

    def __getattr__(name: str) -> Any:
        if name not in homes:
            raise AttributeError(f"module {module!r} has no attribute {name!r}")
        return getattr(importlib.import_module(homes[name]), name)

    return __getattr__


@functools.cache
def _installed() -> tuple[Algorithm, ...]:
    """The algorithms of the entry-point group, but those pointing into nutribench (the
    built-ins, read from :data:`BUILTIN_PACKAGE`: the installed metadata may be another checkout's)."""
    from importlib.metadata import entry_points

    out = []
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        if ep.value.split(":")[0].split(".")[0] == "nutribench":
            continue
        try:
            obj = ep.load()
        except Exception as e:  # noqa: BLE001 - a broken plug-in is named, in one line
            raise AlgorithmRegistryError(
                f"entry point {ep.name} = {ep.value!r} of group {ENTRY_POINT_GROUP}: cannot load it ({e})"
            ) from None
        if not isinstance(obj, Algorithm) or obj.algo != ep.name:
            raise AlgorithmRegistryError(
                f"entry point {ep.name} = {ep.value!r} of group {ENTRY_POINT_GROUP}: must name an "
                f"nutribench.agents.registry.Algorithm whose algo is {ep.name!r}"
            )
        out.append(obj)
    return tuple(out)


def algorithms() -> dict[str, Algorithm]:
    """Every registered algorithm by ``algo``: the built-ins (:func:`builtin_algorithms`: the
    paper's order, ``external`` last), then the installed plug-ins by name, then those
    :func:`register` added."""
    table = {a.algo: a for a in builtin_algorithms()}
    for a in [*sorted(_installed(), key=lambda a: a.algo), *_EXTRA.values()]:
        if table.get(a.algo, a) != a:
            raise AlgorithmRegistryError(f"algorithm {a.algo!r} is registered twice, differently: rename one")
        table[a.algo] = a
    return table


def register(entry: Algorithm) -> Algorithm:
    """Add an algorithm in this process (as an entry point of group :data:`ENTRY_POINT_GROUP`
    does for every process); a name already taken by another entry is refused."""
    if algorithms().get(entry.algo, entry) != entry:
        raise AlgorithmRegistryError(f"algorithm {entry.algo!r} is already registered: give yours another name")
    _EXTRA[entry.algo] = entry
    return entry


def unregister(algo: str) -> None:
    """Remove an algorithm :func:`register` added (tests)."""
    _EXTRA.pop(algo, None)


def reload_installed() -> None:
    """Read the entry-point group and the built-in package again (after installing a package,
    or adding a module, in this process)."""
    for cached in (_installed, builtin_algorithms, _builtin_modules):
        cached.cache_clear()


def get(algo: str) -> Algorithm:
    """The entry of ``algo`` (one-line :class:`ConfigError` naming the known ones)."""
    table = algorithms()
    if not isinstance(algo, str) or algo not in table:
        raise ConfigError(
            f"algo: unknown algorithm {algo!r}: known are {', '.join(table)} (an algorithm of your own: register it "
            f'in the entry-point group {ENTRY_POINT_GROUP}, or algo = "external" with entry_point = "package.module:make_agent")'
        )
    return table[algo]


def names() -> list[str]:
    """The trainable algorithms' names (all but ``external``), the built-ins first in the paper's order."""
    return [a for a, e in algorithms().items() if e.build is not None]


def by_entry_point(algo: str) -> bool:
    """Whether ``algo`` has no builder of its own (``external``): its configs name their
    ``entry_point`` and hold a free ``[params]`` table."""
    entry = algorithms().get(algo)
    return entry is not None and entry.build is None


def paper_names() -> list[str]:
    """The built-in algorithms but ``external`` (the paper's five), in the paper's order."""
    return [a.algo for a in builtin_algorithms() if a.build is not None]


def batched_names() -> list[str]:
    """The algorithms the batched engine trains (those with a batched class), in :func:`names`' order."""
    return [a for a, e in algorithms().items() if e.batched is not None]


def batched_class(algo: str) -> Any:
    """The batched engine's class of ``algo`` (imported now); None if it has none."""
    entry = get(algo)
    return None if entry.batched is None else import_entry_point(entry.batched)


def batch_limit(cfg: Any, horizon: int | None = None) -> str | None:
    """What of config ``cfg`` its batched class does not train as the SB3 one does (None: nothing)."""
    entry = get(cfg.algo)
    return None if entry.batch_limits is None else entry.batch_limits(cfg, horizon)


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
    """``module_name``, installed or beside the user's scripts (the current folder, searched as
    ``python -m`` does). A module found there keeps the folder on ``sys.path``, as under
    ``python -m``: it may import its neighbours later (in ``make_agent`` or ``load``, or SB3
    unpickling its classes); a failed import leaves ``sys.path`` as it was."""
    try:
        return importlib.import_module(module_name)
    except ModuleNotFoundError as e:
        cwd = str(Path.cwd())
        if cwd in sys.path or not (e.name and module_name.startswith(e.name)):
            raise
        sys.path.append(cwd)
        try:
            return importlib.import_module(module_name)
        except BaseException:
            if cwd in sys.path:  # unless the module's own code took it out
                sys.path.remove(cwd)
            raise


def entry_point_source(entry_point: str) -> tuple[str, str | None]:
    """``(entry point, sha256 of its module's file)``: what an external job records."""
    module = _import(entry_point.partition(":")[0])
    path = getattr(module, "__file__", None)
    return entry_point, file_sha256(path)


def algorithm(cfg: Any) -> Algorithm:
    """The registry entry of an agent config."""
    return get(cfg.algo)


def loader_entry_point(cfg: Any) -> str:
    """What loads this config's saved model (written into the model's ``.json`` sidecar as a
    note for plain SB3 and the user; ``TrainedAgent.load`` never imports it from there)."""
    entry = algorithm(cfg)
    if entry.load is not None:
        return entry.load
    if entry.build is not None:
        raise ConfigError(f"algorithm {entry.algo!r}: its registry entry names no loader (load)")
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
