"""Query functions that return pandas DataFrames (pandas is imported only when called).

One line from Python::

    from nutribench.store import read_episode_metrics
    df = read_episode_metrics("nutribench.db", phase="eval")

or with pandas alone: ``pd.read_sql("select * from episode_metrics", "sqlite:///nutribench.db")``.
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from typing import TYPE_CHECKING

from sqlalchemy import Engine, bindparam, text
from sqlalchemy.engine import URL

from nutribench.store.schema import open_store

if TYPE_CHECKING:
    import pandas as pd

Db = str | os.PathLike[str] | URL | Engine
#: A filter on a column: one value or several (None: every row).
Names = Iterable[str] | str | None
Numbers = Iterable[int] | int | None


def _query(db: Db, sql: str, params: dict[str, list] | None = None) -> pd.DataFrame:
    """``sql`` read into a DataFrame from ``db`` (an engine given is left open, one opened here
    disposed), each of ``params`` a list (``IN :name``)."""
    import pandas as pd

    engine = db if isinstance(db, Engine) else open_store(db).engine
    query = text(sql).bindparams(*(bindparam(name, expanding=True) for name in params or {}))
    try:
        with engine.connect() as conn:
            return pd.read_sql(query, conn, params=params)
    finally:
        if engine is not db:
            engine.dispose()


def _where(filters: dict[str, Names | Numbers], *also: str) -> tuple[str, dict[str, list]]:
    """The ``WHERE`` clause of the filters given (a value or several per column), then of the
    conditions ``also``, and its parameters."""
    params = {col: [v] if isinstance(v, (str, int)) else list(v) for col, v in filters.items() if v is not None}
    conditions = [*(f'"{col}" IN :{col}' for col in params), *also]
    return (" WHERE " + " AND ".join(conditions)) if conditions else "", params


def _read(db: Db, view: str, filters: dict, order: str, latest_only: bool) -> pd.DataFrame:
    where, params = _where(filters)
    df = _query(db, f"SELECT * FROM {view}{where} ORDER BY {order}", params)
    if latest_only and len(df):
        df = df[df["regime_version"] == df.groupby("regime")["regime_version"].transform("max")]
        df = df[df["algo_version"] == df.groupby("algo")["algo_version"].transform("max")]
        df = df.reset_index(drop=True)
    return df


def read_episode_metrics(
    db: Db,
    *,
    phase: str | None = None,
    regimes: Names = None,
    algos: Names = None,
    budget: int | None = None,
    latest_only: bool = False,
) -> pd.DataFrame:
    """Rows of the ``episode_metrics`` view (columns in :mod:`nutribench.store.models`).

    ``latest_only`` keeps, per regime and per algo, only the newest config version present.
    """
    filters = {"phase": phase, "regime": regimes, "algo": algos, "budget": budget}
    return _read(db, "episode_metrics", filters, '"job_id", "phase", "episode"', latest_only)


def read_eval_trajectories(
    db: Db,
    *,
    regimes: Names = None,
    algos: Names = None,
    seeds: Numbers = None,
    episode: int | None = None,
    latest_only: bool = False,
) -> pd.DataFrame:
    """Rows of ``eval_trajectories``: one per step of each evaluation episode."""
    filters = {"regime": regimes, "algo": algos, "seed": seeds, "episode": episode}
    return _read(db, "eval_trajectories", filters, '"job_id", "episode", "step"', latest_only)


def read_training_diagnostics(
    db: Db, *, regimes: Names = None, algos: Names = None, seeds: Numbers = None, latest_only: bool = False
) -> pd.DataFrame:
    """Rows of ``training_diagnostics``: one per training update of each job (columns in
    :mod:`nutribench.store.models`, quantities in :mod:`nutribench.diagnostics`), and before
    ``job_id`` a column per other quantity a plug-in's algorithm recorded (from
    ``diagnostic_values``; NaN for an update without it)."""
    from nutribench.diagnostics import COLUMNS

    filters = {"regime": regimes, "algo": algos, "seed": seeds}
    df = _read(db, "training_diagnostics", filters, '"job_id", "update"', latest_only)
    known = ", ".join(f"'{n}'" for n in COLUMNS)  # the vocabulary's names: constants, not input
    where, params = _where(filters, f'"name" NOT IN ({known})')
    other = _query(db, f'SELECT "job_id", "update", "name", "value" FROM diagnostic_values{where}', params)
    if other.empty or df.empty:
        return df
    wide = other.pivot(index=["job_id", "update"], columns="name", values="value")
    extra = sorted(wide.columns)
    out = df.merge(wide[extra].astype("float64").reset_index(), on=["job_id", "update"], how="left")
    return out[[*(c for c in df.columns if c != "job_id"), *extra, "job_id"]]


def read_learning_curve(
    db: Db, *, regimes: Names = None, algos: Names = None, seeds: Numbers = None, latest_only: bool = False
) -> pd.DataFrame:
    """Rows of ``learning_curve``: one per validation day of each evaluation during training
    (columns in :mod:`nutribench.store.models`), ordered by job, training day and day."""
    filters = {"regime": regimes, "algo": algos, "seed": seeds}
    return _read(db, "learning_curve", filters, '"job_id", "train_day", "episode"', latest_only)


def read_jobs(db: Db) -> pd.DataFrame:
    """The jobs table with regime and algo names and versions joined in."""
    return _query(
        db,
        'SELECT r."name" AS regime, r."version" AS regime_version, a."name" AS algo, '
        'a."version" AS algo_version, j.* FROM jobs j '
        'JOIN regimes r ON r."id" = j."regime_id" JOIN agent_configs a ON a."id" = j."agent_config_id" '
        'ORDER BY j."id"',
    )
