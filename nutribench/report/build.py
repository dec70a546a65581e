"""Building the report: read the results database, call the figure and table builders, write
the files under ``reports/``.

Everything here is a thin layer over :mod:`nutribench.report.figures`,
:mod:`nutribench.report.tables` and :mod:`nutribench.report.trajectory` (DataFrame in,
Figure / table out). This module adds what those pure builders do not know about:

* which rows of the database a figure uses: per regime and algorithm the newest config
  versions (``latest_only``) and, per (regime, algorithm, seed), the job with the largest
  training budget (the newest such job if several); what was left out becomes a note;
* Figures 1/2 use the ``train`` phase, Figures 3/4 and the results table the ``eval`` phase;
* the reference lines of Figures 3/4 and the results table's yardsticks
  (:mod:`nutribench.report.references`: the simple policies, played afresh; nothing cached);
* writing: figures as PNG (150 dpi) and PDF, tables as Markdown, LaTeX and CSV.

Problems a user can fix raise :class:`ReportError` (one line); a database that cannot be
read raises :class:`nutribench.store.StoreError`.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from nutribench.config import ConfigError
from nutribench.report.figures import (
    FigureResult,
    algo_label,
    draw_notes,
    eval_across_regimes,
    sort_regimes,
    training_curves,
)
from nutribench.report.references import eval_day_references, simple_policy_references
from nutribench.report.tables import CONFIG_TABLES, TableResult, table_agent_config, table_regimes, table_results, table_training
from nutribench.errors import UserError

#: Figures of the paper this command can build, and the file stem each is written to.
FIGURES: dict[int, str] = {
    1: "fig1_training_return",
    2: "fig2_training_foods",
    3: "fig3_eval_across_regimes",
    4: "fig4_ppo_vs_gru_ppo",
}
#: Tables: 1 (regimes), 2-6 (agent configurations), "results".
TABLES: dict[str, str] = {"1": "table1_regimes", **{str(n): f"table{n}_{a}" for n, a in CONFIG_TABLES.items()}, "results": "table_results",
                           "training": "table_training_vs_authors"}
FIG4_ALGOS = ("ppo", "gru_ppo")
PNG_DPI = 150

Db = str | os.PathLike[str]
Log = Callable[[str], None]


class ReportError(UserError, ValueError):
    """Something the report cannot build from what it was given; printed as one line."""


@dataclass
class ReportData:
    """The episode metrics a report draws from, and what was left out of them (notes)."""

    metrics: pd.DataFrame
    notes: list[str] = field(default_factory=list)

    @property
    def train(self) -> pd.DataFrame:
        return self.metrics[self.metrics["phase"] == "train"]

    @property
    def eval(self) -> pd.DataFrame:
        return self.metrics[self.metrics["phase"] == "eval"]


# --------------------------------------------------------------------------- data
def _keep_latest_versions(df: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """Per regime and per algo, the newest config version present; note what was dropped."""
    notes = []
    for col, ver in (("regime", "regime_version"), ("algo", "algo_version")):
        newest = df.groupby(col)[ver].transform("max")
        old = df[df[ver] < newest]
        if len(old):
            dropped = sorted({f"{n} v{v}" for n, v in old[[col, ver]].drop_duplicates().itertuples(index=False)})
            notes.append(f"older {col} versions left out: {', '.join(dropped)}")
        df = df[df[ver] == newest]
    return df, notes


def _keep_largest_budget(df: pd.DataFrame) -> tuple[pd.DataFrame, list[str]]:
    """Per (regime, algo) the largest training budget; per seed of it the newest job."""
    notes = []
    largest = df.groupby(["regime", "algo"])["budget"].transform("max")
    mixed = df.groupby(["regime", "algo"])["budget"].nunique()
    for (regime, algo), n in mixed[mixed > 1].items():
        budgets = sorted(df[(df["regime"] == regime) & (df["algo"] == algo)]["budget"].unique())
        notes.append(f"{algo_label(algo)}/{regime}: budgets {', '.join(map(str, budgets))} in the database, the largest ({budgets[-1]}) shown")
    df = df[df["budget"] == largest]
    newest_job = df.groupby(["regime", "algo", "seed"])["job_id"].transform("max")
    if (df["job_id"] != newest_job).any():
        notes.append("several jobs for one regime/algo/seed/budget: the newest of each shown")
    return df[df["job_id"] == newest_job], notes


def load_report_data(db: Db, latest_only: bool = True) -> ReportData:
    """All episode metrics of ``db`` that a report uses (see the module docstring).

    Raises :class:`nutribench.store.StoreError` for a missing, empty or outdated database
    and :class:`ReportError` when it holds no episodes yet.
    """
    from nutribench.store import open_store, read_episode_metrics

    store = open_store(db)
    try:
        df = read_episode_metrics(store.engine)
    finally:
        store.dispose()
    if df.empty:
        raise ReportError(f"{store.display} holds no finished episodes yet: `nutribench run --db {db}` fills it")
    notes: list[str] = []
    if latest_only:
        df, notes = _keep_latest_versions(df)
    df, budget_notes = _keep_largest_budget(df)
    return ReportData(df.reset_index(drop=True), notes + budget_notes)


# --------------------------------------------------------------------------- writing
def write_figure(fig_result: FigureResult | Figure, out_dir: Db, stem: str) -> list[Path]:
    """Write ``<out_dir>/<stem>.png`` (150 dpi) and ``.pdf``; return both paths."""
    fig = fig_result.figure if isinstance(fig_result, FigureResult) else fig_result
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{stem}.png", out / f"{stem}.pdf"]
    fig.savefig(paths[0], dpi=PNG_DPI)
    fig.savefig(paths[1])
    return paths


def write_table(table_result: TableResult, out_dir: Db, stem: str) -> list[Path]:
    """Write ``<out_dir>/<stem>.md``, ``.tex`` and ``.csv``; return the three paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / f"{stem}.md", out / f"{stem}.tex", out / f"{stem}.csv"]
    paths[0].write_text(table_result.to_markdown())
    paths[1].write_text(table_result.to_latex())
    paths[2].write_text(table_result.to_csv())
    return paths


def _add_notes(res: FigureResult, extra: Sequence[str]) -> FigureResult:
    """Put notes the builder did not know about (budgets, versions) on the figure."""
    extra = [n for n in extra if n not in res.notes]
    if extra:
        res.notes = [*res.notes, *extra]
        draw_notes(res.figure, res.notes)
    return res


# --------------------------------------------------------------------------- figures and tables
def build_figure(number: int, data: ReportData, reference_episodes: int = 200, log: Log | None = None) -> FigureResult:
    """Figure 1-4 of the paper from ``data``; :class:`ReportError` when it has nothing to draw."""
    try:
        if number in (1, 2):
            if data.train.empty:
                raise ReportError(f"figure {number}: no training episodes in the database")
            # the dashed "best" line marks the best return (Figure 1); most foods eaten is no "best"
            res = training_curves(data.train, "return" if number == 1 else "foods", best_line=number == 1)
        elif number in (3, 4):
            algos = list(FIG4_ALGOS) if number == 4 else None
            ev = data.eval if algos is None else data.eval[data.eval["algo"].isin(algos)]
            if ev.empty:
                what = f" for {', '.join(algo_label(a) for a in algos)}" if algos else ""
                raise ReportError(f"figure {number}: no evaluation episodes{what} in the database")
            refs = simple_policy_references(sort_regimes(ev["regime"]), episodes=reference_episodes, log=log)
            title = "PPO against GRU-PPO: fixed-policy inference across regimes" if number == 4 else "Fixed-policy inference across regimes"
            res = eval_across_regimes(data.eval, algos=algos, references=refs, title=title)
        else:
            raise ReportError(f"no figure {number}: the figures are 1, 2, 3, 4")
    except ValueError as e:
        if isinstance(e, ReportError):
            raise
        raise ReportError(f"figure {number}: {e}") from None
    # what load_report_data left out (older versions, smaller budgets) goes on the figure too
    return _add_notes(res, data.notes)


def _stored_agent_config(db: Db, algo: str) -> Any | None:
    """The newest agent config of ``algo`` recorded in ``db`` (for Tables 2-6 when the config
    file is missing), as an object :func:`table_agent_config` accepts; None if none."""
    from sqlalchemy import select

    from nutribench.store import AgentConfig, StoreError, open_store, session_scope

    try:
        store = open_store(db)
    except StoreError:
        return None
    try:
        with session_scope(store.engine) as s:
            row = s.scalars(select(AgentConfig).where(AgentConfig.algo == algo).order_by(AgentConfig.version.desc())).first()
            if row is None:
                return None
            return _StoredConfig(row.name, dict(row.body))
    finally:
        store.dispose()


@dataclass
class _StoredConfig:
    name: str
    body: dict[str, Any]

    def model_dump(self, mode: str = "json") -> dict[str, Any]:
        return self.body


def _with_notes(res: TableResult, data: ReportData) -> TableResult:
    """What was left out of the data, in the table's caption as on the figures."""
    if data.notes:
        res.title += " (note: " + "; ".join(data.notes) + ")"
    return res


def build_table(key: str, data: ReportData | None = None, db: Db | None = None) -> TableResult:
    """Table ``key`` ("1".."6" or "results"). Table 1 reads the regime files; Tables 2-6 the
    agent config files (else the newest config of that algorithm stored in ``db``); the
    results table the evaluation episodes of ``data``."""
    if key == "1":
        from nutribench.config import list_regimes, load_env_config

        names = list_regimes()
        if not names:
            raise ReportError("table 1: no regime files found")
        return table_regimes([load_env_config(n) for n in names])
    if key in TABLES and key.isdigit():
        number = int(key)
        algo = CONFIG_TABLES[number]
        try:
            from nutribench.agents.config import load_agent_config

            config = load_agent_config(algo)
        except (ImportError, ConfigError) as e:
            config = _stored_agent_config(db, algo) if db is not None else None
            if config is None:
                raise ReportError(f"table {number}: no {algo} agent config file and none in the database ({e})") from None
        return table_agent_config(number, config)
    if key == "results":
        if data is None:
            raise ReportError("the results table needs the episode metrics of the database")
        ev = data.eval
        if ev.empty:
            raise ReportError("results table: no evaluation episodes in the database")
        return _with_notes(table_results(ev, references=eval_day_references(ev)), data)
    if key == "training":
        if data is None or data.train.empty:
            raise ReportError("training table: no training episodes in the database")
        return _with_notes(table_training(data.train), data)
    raise ReportError(f"no table {key!r}: the tables are {', '.join(TABLES)}")


def build_report(
    db: Db,
    out: Db = "reports",
    figs: Iterable[int] = (),
    tables: Iterable[str | int] = (),
    all: bool = False,  # noqa: A002 - mirrors the --all option
    reference_episodes: int = 200,
    log: Log | None = None,
) -> list[Path]:
    """Write the requested figures and tables under ``out`` and return the paths written.

    ``all=True`` builds Figures 1-4, Tables 1-6, the results and the training tables; what the database
    cannot support (e.g. Figure 4 without PPO or GRU-PPO results) is skipped and reported
    through ``log``. An item asked for by number that cannot be built raises
    :class:`ReportError`. ``reference_episodes``: episodes per simple policy and regime for
    the reference lines of Figures 3/4.
    """
    figs = list(FIGURES) if all else [int(f) for f in figs]
    tables = list(TABLES) if all else [str(t) for t in tables]
    for f in figs:
        if f not in FIGURES:
            raise ReportError(f"no figure {f}: the figures are {', '.join(map(str, FIGURES))}")
    for t in tables:
        if t not in TABLES:
            raise ReportError(f"no table {t!r}: the tables are {', '.join(TABLES)}")
    if not figs and not tables:
        raise ReportError("nothing to build: ask for figures, tables or all")
    # the database is read once, up front, and only when something needs it: a database that
    # cannot be read (missing, empty, outdated) fails the whole command, even with ``all``
    data = load_report_data(db) if figs or "results" in tables or "training" in tables else None
    if data is not None and log:
        for note in data.notes:
            log(f"note: {note}")

    def built(make: Callable[[], Any]) -> Any:
        """What ``make`` builds; with ``all``, None (and a log line) for what the data cannot give."""
        try:
            return make()
        except ReportError as e:
            if not all:
                raise
            if log:
                log(f"skipped: {e}")
            return None

    paths: list[Path] = []
    for f in figs:
        res = built(lambda: build_figure(f, data, reference_episodes=reference_episodes, log=log))
        if res is not None:
            paths += write_figure(res, out, FIGURES[f])
    for t in tables:
        res_t = built(lambda: build_table(t, data, db))
        if res_t is not None:
            paths += write_table(res_t, out, TABLES[t])
    return paths


# --------------------------------------------------------------------------- trajectory
def build_trajectory(db: Db, algo: str, regime: str, seed: int, episode: int = 0, out: Db = "reports") -> list[Path]:
    """The trajectory view of one evaluation episode, written as PNG and PDF.

    Uses the newest config versions and, if several jobs match, the largest budget.
    """
    from nutribench.env import RegimeDynamics
    from nutribench.report.trajectory import trajectory_figure
    from nutribench.store import open_store, read_eval_trajectories

    store = open_store(db)
    try:
        steps = read_eval_trajectories(store.engine, regimes=regime, algos=algo, seeds=seed, episode=episode, latest_only=True)
        if steps.empty:
            have = read_eval_trajectories(store.engine, latest_only=True)
            raise ReportError(f"no evaluation steps for {algo}/{regime} seed {seed} episode {episode} in {store.display}" + _available(have))
    finally:
        store.dispose()
    budget = int(steps["budget"].max())
    steps = steps[steps["budget"] == budget]
    steps = steps[steps["job_id"] == steps["job_id"].max()]
    dynamics = RegimeDynamics(regime)
    ret = float(np.sum(steps["reward"].to_numpy(dtype=float)))
    title = f"{algo_label(algo)} on {regime}, seed {seed}, evaluation episode {episode} (budget {budget} episodes): return {ret:.2f}, {int(steps['action'].sum())} meals"
    fig = trajectory_figure(steps[["step", "food", "action", "C", "F", "P"]], dynamics, title=title)
    return write_figure(fig, out, f"trajectory_{regime}_{algo}_seed{seed}_ep{episode}")


#: Cells listed in "trajectory not found" before "... N more".
AVAILABLE_SHOWN = 4


def _available(steps: pd.DataFrame) -> str:
    if steps.empty:
        return " (the database holds no evaluation steps)"
    cells = steps[["algo", "regime", "seed"]].drop_duplicates()
    parts = [f"{a}/{r} seeds {','.join(map(str, sorted(g['seed'])))}" for (a, r), g in cells.groupby(["algo", "regime"])]
    eps = sorted(steps["episode"].unique())
    shown = "; ".join(parts[:AVAILABLE_SHOWN]) + (f"; ... {len(parts) - AVAILABLE_SHOWN} more" if len(parts) > AVAILABLE_SHOWN else "")
    return (f"; available: {shown} (episodes {eps[0]}-{eps[-1]}; all of them: "
            "nutribench status, or SELECT DISTINCT algo, regime, seed FROM episode_metrics WHERE phase = 'eval')")


__all__ = [
    "FIGURES",
    "TABLES",
    "ReportData",
    "ReportError",
    "build_figure",
    "build_report",
    "build_table",
    "build_trajectory",
    "eval_day_references",
    "load_report_data",
    "simple_policy_references",
    "write_figure",
    "write_table",
]
