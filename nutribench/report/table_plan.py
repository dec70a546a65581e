"""The report's table plan: which tables a ``nutribench report`` call builds and the file
stem of each (:func:`table_plan`), what a table key names (:func:`resolve_table`: "1", a
config table's number or its config's name, "results", "training", "aggregate"), whether the
database's stored agent configs must be read for it (:func:`needs_stored_configs`), and the
config tables themselves (:func:`config_table`: a built-in config from its file, any other as
stored in the database). Used by :mod:`nutribench.report.build`."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from nutribench.config import ConfigError
from nutribench.report.data import DbFile, ReportError, stored_agent_configs
from nutribench.report.tables import CONFIG_TABLES, TableResult, config_table_numbers, table_agent_config

#: Tables: 1 (regimes), 2-6 (the built-in agent configurations), "results", "training",
#: "aggregate"; the other configs of a database add Tables 7, 8, ... (``table<N>_<name>``).
TABLES: dict[str, str] = {
    "1": "table1_regimes",
    **{str(n): f"table{n}_{a}" for n, a in CONFIG_TABLES.items()},
    "results": "table_results",
    "training": "table_training_vs_authors",
    "aggregate": "table_aggregate",
}


def stored_or_none(db: DbFile | None) -> dict[str, Any]:
    """:func:`stored_agent_configs` of ``db``; empty when there is no readable database."""
    from nutribench.store import StoreError

    try:
        return stored_agent_configs(db) if db is not None else {}
    except StoreError:
        return {}


def resolve_table(key: str, numbers: dict[int, str]) -> tuple[str, str]:
    """(key, file stem) of table ``key``: "1", a config table's number or its config's name,
    "results", "training" or "aggregate"; ``numbers``: :func:`config_table_numbers` of the database."""
    by_name = {name: n for n, name in numbers.items()}
    key = str(by_name.get(key, key))
    if key.isdigit() and int(key) in numbers:
        return key, f"table{key}_{numbers[int(key)]}"
    if key in TABLES:
        return key, TABLES[key]
    listed = ", ".join(["1", *(f"{n} ({name})" for n, name in numbers.items()), "results", "training", "aggregate"])
    raise ReportError(f"no table {key} (--table {key}): the tables are {listed}")


def config_table(number: int, name: str, db: DbFile | None, stored: dict[str, Any] | None) -> TableResult:
    """Table ``number``: a built-in config from its file (else as stored in ``db``); any other
    config as stored in ``db`` (the body it ran with)."""
    config, why = None, ""
    if name in CONFIG_TABLES.values():
        try:
            from nutribench.agents.config import load_agent_config

            config = load_agent_config(name)
        except (ImportError, ConfigError) as e:
            why = f" ({e})"
    if config is None:
        config = (stored if stored is not None else stored_or_none(db)).get(name)
    if config is None:
        raise ReportError(f"table {number}: no {name} agent config file and none in the database{why}")
    return table_agent_config(number, config)


def table_plan(
    tables: Sequence[str], all: bool, stored: dict[str, Any] | None, algos: Sequence[str] | None
) -> dict[str, str]:  # noqa: A002
    """Table key -> file stem of every table to build, checked. ``all`` (or "all" among
    ``tables``): Table 1, the config tables of ``algos`` (default every config: 2-6 and the
    database's others), the results, the training and the aggregate tables."""
    numbers = config_table_numbers(stored or ())
    keys = [t for t in tables if t != "all"]
    if all or "all" in tables:
        configs = [str(n) for n, name in numbers.items() if algos is None or name in algos]
        keys = ["1", *configs, "results", "training", "aggregate", *keys]
    return dict(resolve_table(k, numbers) for k in keys)  # a key named twice keeps its first place


def unheld_tables(
    plan: dict[str, str], stored: dict[str, Any] | None, metrics: Any, asked: Sequence[str] = ()
) -> dict[str, str]:
    """Key -> why, for the config tables of ``plan`` whose agent config has no episodes in
    ``metrics`` (rows of ``episode_metrics``): ``--all`` leaves them out (a report draws what
    the database holds); a table asked for by its key or name (``asked``) is kept."""
    numbers = config_table_numbers(stored or ())
    held = set(metrics["algo"]) if len(metrics) else set()
    out = {}
    for key in plan:
        name = numbers.get(int(key)) if key.isdigit() and key != "1" else None
        if name is None or name in held or key in asked or name in asked:
            continue
        out[key] = f"table {key} ({name}): no results of {name} in the database (--table {key} builds it all the same)"
    return out


def needs_stored_configs(figs: list[int], tables: list[str], all: bool, algos: Sequence[str] | None) -> bool:  # noqa: A002
    """Whether the database's agent configs must be read: to check ``algos`` or the pair, to
    find Figure 4's configs without memory (:mod:`nutribench.report.figure4`), or to find the
    tables of configs other than the five."""
    if all or 4 in figs or any(t not in TABLES for t in tables):
        return True
    return algos is not None and bool(figs or [t for t in tables if t != "1"])
