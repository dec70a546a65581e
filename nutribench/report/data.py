"""The data a report draws, read from the results database and selected: :class:`ReportData`
(the episode metrics and the notes on what was left out), :func:`read_metrics` (every row
of ``episode_metrics``), :func:`prepare` (the rows of the configs asked for; per regime and
algorithm the newest config versions, per (regime, algorithm, seed) the job with the largest
training budget, the newest such job if several; a palette over every config of the
database) and :func:`load_report_data` (both); :func:`prepare_entries` (the rows the
leaderboard and ``compare`` draw: every entry, an agent config's name, version and training
budget, kept apart, none hidden by another; per entry and (regime, seed) the newest job),
:func:`stored_agent_configs` (the newest body
of each agent config recorded), and the checks of names read from a database or given on the
command line (:func:`check_names`, :func:`check_known`), which raise :class:`ReportError`, the
one-line error of every report problem a user can fix. :mod:`nutribench.report.build`
re-exports all of it.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import pandas as pd

from nutribench.errors import UserError
from nutribench.report.palette import Palette, palette
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos

#: a database file (or folder) the report reads or writes by its path
DbFile = str | os.PathLike[str]

#: what the report prints its progress lines with (print, a command's echo)
Log = Callable[[str], None]


def quiet(msg: str) -> None:
    """The :data:`Log` of a caller that gave none: it says nothing."""


class ReportError(UserError, ValueError):
    """Something the report cannot build from what it was given; printed as one line."""


def check_names(names: Iterable[Any], what: str, where: str) -> None:
    """:class:`ReportError` for a name that is not a regime or config name
    (``[a-z][a-z0-9_]*``): names read from a database become file names and regime files here
    (``table7_<name>``, ``trajectory_<regime>_<algo>_...``, the regime file of the reference
    lines), so ``../x`` or ``/etc/y`` must never get that far."""
    from nutribench.store.archive import NAME_MAX, valid_config_name

    bad = [n for n in dict.fromkeys(names) if not valid_config_name(n)]
    if bad:
        shown = repr(bad[0]) if len(repr(bad[0])) <= 80 else repr(bad[0])[:77] + "..."
        raise ReportError(
            f"{where}: {what} {shown} is not a name ([a-z][a-z0-9_]*, at most {NAME_MAX} characters): "
            "no file is built from it"
        )


@dataclass
class ReportData:
    """The episode metrics a report draws from, and what was left out of them (notes)."""

    metrics: pd.DataFrame
    notes: list[str] = field(default_factory=list)
    #: the configs asked for (None: every config of the database)
    selected: tuple[str, ...] | None = None
    #: the colours of every config of the database, so each figure colours a name alike
    colors: Palette | None = None

    def what(self) -> str:
        """`` for a2c_mine, PPO`` when configs were selected, else ``""`` (for messages)."""
        return f" for {', '.join(algo_label(a) for a in self.selected)}" if self.selected else ""

    def rows(self, phase: str, what: str) -> pd.DataFrame:
        """The rows of ``phase`` (``train`` or ``eval``); :class:`ReportError` naming ``what`` (the
        figure or table that needs them) when there are none."""
        rows = self.metrics[self.metrics["phase"] == phase]
        if rows.empty:
            kind = "training" if phase == "train" else "evaluation"
            raise ReportError(f"{what}: no {kind} episodes{self.what()} in the database")
        return rows

    @property
    def eval(self) -> pd.DataFrame:
        return self.metrics[self.metrics["phase"] == "eval"]


def _keep_newest(df: pd.DataFrame, col: str, ver: str) -> tuple[pd.DataFrame, list[str]]:
    """Per ``col`` (regime or algo) the newest ``ver`` present; a note naming what was dropped."""
    newest = df.groupby(col)[ver].transform("max")
    old = df[df[ver] < newest]
    notes = []
    if len(old):
        dropped = sorted({f"{n} v{v}" for n, v in old[[col, ver]].drop_duplicates().itertuples(index=False)})
        notes.append(f"older {col} versions left out: {', '.join(dropped)}")
    return df[df[ver] == newest], notes


def _keep_largest_budget(df: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """Per (regime, algo) the largest training budget; per seed of it the newest job."""
    notes = []
    largest = df.groupby(["regime", "algo"])["budget"].transform("max")
    mixed = df.groupby(["regime", "algo"])["budget"].nunique()
    for regime, algo in mixed[mixed > 1].index:
        budgets = sorted(df[(df["regime"] == regime) & (df["algo"] == algo)]["budget"].unique())
        notes.append(
            f"{algo_label(algo)}/{regime}: budgets {', '.join(map(str, budgets))} in the database, the largest ({budgets[-1]}) shown"
        )
    df, others = largest_budget_jobs(df[df["budget"] == largest])
    if others:
        notes.append("several jobs for one regime/algo/seed/budget: the newest of each shown")
    return df, notes


def largest_budget_jobs(rows: pd.DataFrame, by: Sequence[str] = ("regime", "algo", "seed")) -> tuple[pd.DataFrame, int]:
    """The rows of one job per run (``by``): the one of the largest budget, the newest such job
    if several; and how many other jobs were left out."""
    jobs = rows[[*by, "budget", "job_id"]].drop_duplicates("job_id").sort_values(["budget", "job_id"])
    keep = jobs.groupby(list(by)).tail(1)["job_id"]
    return rows[rows["job_id"].isin(keep)], len(jobs) - len(keep)


def read_metrics(db: DbFile) -> pd.DataFrame:
    """Every row of ``db``'s ``episode_metrics`` view (:func:`read_episodes`)."""
    return read_episodes(db)


def read_episodes(db: DbFile, phase: str | None = None, error: type[UserError] = ReportError) -> pd.DataFrame:
    """The rows of ``db``'s ``episode_metrics`` view (``phase``: of that phase alone, e.g. the
    evaluation days, without the training days, by far the most), their names checked
    (:func:`check_names`). Raises :class:`nutribench.store.StoreError` for a missing, empty or
    outdated database and ``error`` (one line, the command that fills it) when it holds none yet.
    """
    from nutribench.store import open_store, read_episode_metrics
    from nutribench.store.schema import db_command

    with open_store(db) as store:
        df = read_episode_metrics(store.engine, phase=phase)
    if df.empty:
        what = "evaluation days" if phase == "eval" else "finished episodes"
        raise error(f"{store.display} holds no {what} yet: {db_command('nutribench run', store.url)} fills it")
    check_names(df["regime"].unique(), "regime", store.display)
    check_names(df["algo"].unique(), "agent config", store.display)
    return df


def _selected(df: pd.DataFrame, algos: Sequence[str] | None) -> tuple[pd.DataFrame, tuple[str, ...] | None, Palette]:
    """The rows of ``algos`` (None: all), the names selected (None: all), a palette over every
    config of ``df`` (so each figure colours a name alike)."""
    selected = tuple(sort_algos(algos)) if algos is not None else None
    rows = df[df["algo"].isin(selected)] if selected is not None else df
    return (rows.reset_index(drop=True) if rows.empty else rows), selected, palette(df["algo"].unique())


def prepare(df: pd.DataFrame, algos: Sequence[str] | None = None, latest_only: bool = True) -> ReportData:
    """The rows of ``df`` (all of ``episode_metrics``) a report draws: those of ``algos``
    (default every config), the newest versions and largest budgets of them, and notes on
    what was left out. Its palette covers every config of ``df``."""
    df, selected, colors = _selected(df, algos)
    if df.empty:
        return ReportData(df, [], selected, colors)
    notes: list[str] = []
    if latest_only:  # per regime and per algo, the newest config version present
        df, notes = _keep_newest(df, "regime", "regime_version")
        df, algo_notes = _keep_newest(df, "algo", "algo_version")
        notes += algo_notes
    df, budget_notes = _keep_largest_budget(df)
    return ReportData(df.reset_index(drop=True), notes + budget_notes, selected, colors)


#: What one entry of the leaderboard and of ``compare`` is: an agent config's name, its
#: version and the training budget of its jobs (days). Entries are never merged: the paper
#: archives' ``ppo`` v1 at 5000 days and a user's ``ppo`` v2 at 150 days are two entries.
ENTRY: tuple[str, ...] = ("algo", "algo_version", "budget")


def prepare_entries(df: pd.DataFrame, algos: Sequence[str] | None = None) -> ReportData:
    """The rows of ``df`` (``episode_metrics``) the leaderboard and ``compare`` draw: those of
    ``algos`` (default every config), every :data:`ENTRY` (name, version, budget) kept, none
    hidden by another (unlike :func:`prepare`, which keeps each config's newest version and
    largest budget); per regime the newest regime version; per entry and (regime, seed) the
    newest job. The notes say what was left out."""
    df, selected, colors = _selected(df, algos)
    if df.empty:
        return ReportData(df, [], selected, colors)
    # an older regime version is another task, its days not scored on today's yardsticks
    df, notes = _keep_newest(df, "regime", "regime_version")
    key = [*ENTRY, "regime", "seed"]
    newest_job = df.groupby(key)["job_id"].transform("max")
    if (df["job_id"] != newest_job).any():
        notes.append(
            "several jobs for one entry (agent, version, budget) on one regime and seed: the newest of each shown"
        )
    return ReportData(df[df["job_id"] == newest_job].reset_index(drop=True), notes, selected, colors)


def entries(df: pd.DataFrame) -> list[tuple[str, int, int]]:
    """The entries (name, version, budget) of ``df``, in palette order of the names, then by
    budget and version, the largest first."""
    keys = {(str(a), int(v), int(b)) for a, v, b in df[list(ENTRY)].drop_duplicates().itertuples(index=False)}
    rank = {a: i for i, a in enumerate(sort_algos({k[0] for k in keys}))}
    return sorted(keys, key=lambda k: (rank[k[0]], -k[2], -k[1]))


def entry_rows(df: pd.DataFrame, entry: tuple[str, int, int]) -> pd.DataFrame:
    """The rows of ``df`` of one entry (name, version, budget)."""
    return df[(df[list(ENTRY)] == pd.Series(entry, index=list(ENTRY))).all(axis=1)]


def entry_label(entry: tuple[str, int, int]) -> str:
    """``ppo v1, 5000 days``: how captions and notes name an entry."""
    name, version, budget = entry
    return f"{name} v{version}, {budget} day{'' if budget == 1 else 's'}"


def load_report_data(db: DbFile, latest_only: bool = True, algos: Sequence[str] | None = None) -> ReportData:
    """The episode metrics of ``db`` that a report of ``algos`` (default: every config) uses;
    see :func:`read_metrics` and :func:`prepare`."""
    return prepare(read_metrics(db), algos, latest_only)


def stored_agent_configs(db: DbFile) -> dict[str, Any]:
    """The newest version of each agent config recorded in ``db``, by name (in palette
    order), as objects :func:`table_agent_config` accepts. Raises
    :class:`nutribench.store.StoreError` for a database that cannot be read."""
    from sqlalchemy import select

    from nutribench.store import AgentConfig, open_store, session_scope

    with open_store(db) as store:
        with session_scope(store.engine) as s:
            rows = s.execute(select(AgentConfig.name, AgentConfig.version, AgentConfig.body)).all()
    check_names([name for name, _, _ in rows], "agent config", store.display)
    newest = {name: body for name, _, body in sorted(rows, key=lambda row: row[1])}  # the newest version last
    return {n: _StoredConfig(n, dict(newest[n])) for n in sort_algos(newest)}


def check_known(names: Sequence[str], held: Iterable[str], option: str) -> None:
    """:class:`ReportError` (one line, what the database holds) for names not in ``held``."""
    held = sort_algos(held)
    unknown = [n for n in names if n not in held]
    if unknown:
        raise ReportError(
            f"{option} {', '.join(unknown)}: not in the database, which holds {', '.join(held) or 'no agent configs'}"
        )


@dataclass
class _StoredConfig:
    name: str
    body: dict[str, Any]

    def model_dump(self, mode: str = "json") -> dict[str, Any]:
        return self.body
