"""Building the report: read the results database, call the figure and table builders, write
the files under ``reports/``.

Everything here is a thin layer over :mod:`nutribench.report.figures`,
:mod:`nutribench.report.tables` and :func:`nutribench.report.output.trajectory_figure` (DataFrame in,
Figure / table out). This module adds what those pure builders do not know about:

* which agent configs a report draws (``algos``: default every config in the database) and
  which pair Figure 4 compares (``pair``: default PPO and GRU-PPO, checked by :func:`check_pair`;
  and beside it its memory ablation, :func:`without_memory`: each config the database holds
  that is one of the pair's configs with ``memory = false`` and nothing else changed; a
  database without one draws the pair alone); colours are one palette
  per database (:mod:`nutribench.report.palette`), so a config looks the same in every figure;
* which rows of the database a figure uses (:mod:`nutribench.report.data`): per regime and
  algorithm the newest config versions (``latest_only``) and, per (regime, algorithm, seed),
  the job with the largest training budget (the newest such job if several), chosen among
  the selected configs alone (a report of some configs is the report of a database holding
  only those); what was left out becomes a note;
* Figures 1/2 use the ``train`` phase, Figures 3/4 and the results table the ``eval`` phase;
* the reference lines of Figures 3/4 and the results table's yardsticks
  (:mod:`nutribench.report.references`: the simple policies, played afresh; nothing cached);
* Tables 2-6 from the five built-in agent config files, Tables 7, 8, ... from the bodies of
  the other configs stored in the database (:func:`nutribench.report.tables.config_table_numbers`);
  which tables a call builds and the file stem of each (:func:`table_plan`), what a table key
  names (:func:`resolve_table`: "1", a config table's number or its config's name, "results",
  "training", "aggregate"), whether the database's stored agent configs must be read for it
  (:func:`needs_stored_configs`), and the config tables themselves (:func:`config_table`: a
  built-in config from its file, any other as stored in the database);
* writing (:mod:`nutribench.report.output`): figures as PNG (150 dpi) and PDF, tables as
  Markdown, LaTeX and CSV, and the trajectory view of one evaluation episode; with ``all``,
  ``index.html``, the report on one static page (:mod:`nutribench.report.html`), with the
  leaderboard (:mod:`nutribench.report.leaderboard`) as its last section.

The names of :mod:`nutribench.report.data` and :mod:`nutribench.report.output` are importable
from here too. Problems a user can fix raise :class:`ReportError` (one line); a database that
cannot be read raises :class:`nutribench.store.StoreError`.

"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from functools import partial
from pathlib import Path
from typing import Any

import pandas as pd

from nutribench.config import ConfigError, list_regimes, load_env_config
from nutribench.report.data import (
    DbFile,
    Log,
    ReportData,
    ReportError,
    check_known,
    check_names,
    load_report_data,
    prepare,
    quiet,
    read_metrics,
    stored_agent_configs,
)
from nutribench.report.figure_parts import FigureResult, budget_caption, draw_notes, sort_regimes
from nutribench.report.figures import eval_across_regimes, training_curves
from nutribench.report.html import page_figure, page_table, write_index
from nutribench.report.output import build_trajectory, write_figure, write_table
from nutribench.report.palette import label as algo_label
from nutribench.report.references import aggregate_points, eval_day_references, simple_policy_references
from nutribench.report.tables import (
    CONFIG_TABLES,
    TableResult,
    config_table_numbers,
    table_agent_config,
    table_regimes,
    table_results,
    table_training,
)

#: Figures of the paper this command can build, and the file stem each is written to.
FIGURES: dict[int, str] = {
    1: "fig1_training_return",
    2: "fig2_training_foods",
    3: "fig3_eval_across_regimes",
    4: "fig4_ppo_vs_gru_ppo",
    5: "fig5_aggregate",  # not the paper's: aggregate scores with rliable (nutribench.report.aggregate)
    6: "fig6_learning_curve",  # not the paper's: evaluation during training (nutribench.report.learning)
}
#: ``--fig`` names of figures
FIGURE_NAMES: dict[str, int] = {"aggregate": 5, "learning": 6}
#: Figure 4's default pair (its file keeps the name ``fig4_ppo_vs_gru_ppo``).
DEFAULT_PAIR = ("ppo", "gru_ppo")


# --------------------------------------------------------------------------- Figure 4's configs
#: what may differ between a config and its copy without memory (Figure 4's memory ablation)
_OWN = ("name", "version", "description", "memory")


def check_pair(pair: Sequence[str] | None, default: tuple[str, str]) -> tuple[str, str]:
    """``pair`` as a tuple (None: ``default``); :class:`ReportError` unless two different names."""
    if pair is None:
        return default
    if len(pair) != 2 or pair[0] == pair[1]:
        raise ReportError(f"--pair {','.join(pair)}: give two different agent configs, e.g. --pair ppo,gru_ppo")
    check_names(pair, "agent config", "--pair")
    return (pair[0], pair[1])


def _rest(body: Mapping[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in body.items() if k not in _OWN}


def without_memory(
    pair: Sequence[str], stored: Mapping[str, Any] | None, metrics: pd.DataFrame | None = None
) -> dict[str, str]:
    """The configs of ``stored`` (:func:`~nutribench.report.data.stored_agent_configs`) that
    are a config of ``pair`` with ``memory = false`` and nothing else changed, each mapped to
    that config of the pair, in ``stored``'s order (each drawn as ``<label> without memory
    (<name>)``, so that with the ladder study's archives, ``reports/ladder/``, Figure 4 shows
    PPO, GRU-PPO and GRU-PPO without memory; GRU-PPO's option: the state zeroed before every
    step); only those with evaluation episodes in ``metrics`` (rows of ``episode_metrics``)
    when it is given; none where ``stored`` is None."""
    out: dict[str, str] = {}
    members = {m: stored[m].model_dump(mode="json") for m in pair if stored and m in stored}
    evaluated = None if metrics is None else set(metrics.loc[metrics["phase"] == "eval", "algo"])
    for name, cfg in (stored or {}).items():
        body = cfg.model_dump(mode="json")
        if name in pair or body.get("memory", True) is not False or (evaluated is not None and name not in evaluated):
            continue
        same = [m for m, mb in members.items() if mb.get("memory", True) is True and _rest(mb) == _rest(body)]
        if same:
            out[name] = same[0]
    return out


def ablation_labels(ablation: Mapping[str, str]) -> dict[str, str]:
    """The legend labels of the ablation's configs: ``GRU-PPO without memory (gru_ppo_nomem)``."""
    return {name: f"{algo_label(member)} without memory ({name})" for name, member in ablation.items()}


def pair_title(pair: Sequence[str], ablation: Mapping[str, str]) -> str:
    """The figure's first title line: ``PPO against GRU-PPO with and without memory``."""
    ablated = set(ablation.values())
    a, b = (f"{algo_label(m)} with and without memory" if m in ablated else algo_label(m) for m in pair)
    return f"{a} against {b}: fixed-policy inference across regimes"


# --------------------------------------------------------------------------- the table plan
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
    find Figure 4's configs without memory (:func:`without_memory`), or to find the
    tables of configs other than the five."""
    if all or 4 in figs or any(t not in TABLES for t in tables):
        return True
    return algos is not None and bool(figs or [t for t in tables if t != "1"])


def _add_notes(res: FigureResult, extra: Sequence[str]) -> FigureResult:
    """Put notes the builder did not know about (budgets, versions) on the figure."""
    extra = [n for n in extra if n not in res.notes]
    if extra:
        res.notes = [*res.notes, *extra]
        draw_notes(res.figure, res.notes)
    return res


# --------------------------------------------------------------------------- figures and tables
def figure_stem(number: int, pair: Sequence[str] | None = None) -> str:
    """The file stem of figure ``number``; Figure 4's follows its pair (``fig4_a_vs_b``)."""
    if number == 4 and pair is not None and tuple(pair) != DEFAULT_PAIR:
        return f"fig4_{pair[0]}_vs_{pair[1]}"
    return FIGURES[number]


def _eval_figure(
    number: int,
    data: ReportData,
    pair: Sequence[str],
    reference_episodes: int,
    log: Log | None,
    ablation: dict[str, str] | None,
) -> FigureResult:
    """Figure 3 (every config of ``data``) or Figure 4 (``pair``, then ``ablation``'s configs)."""
    ablation = dict(ablation or {})
    algos = [*pair, *ablation] if number == 4 else None
    ev = data.eval if algos is None else data.eval[data.eval["algo"].isin(algos)]
    # Figure 4 compares its pair: with one of them missing there is no comparison to draw
    missing = [a for a in pair if a not in set(ev["algo"])] if number == 4 else []
    if missing and not ev.empty:
        raise ReportError(
            f"figure {number}: no evaluation episodes for {', '.join(algo_label(a) for a in missing)} in the "
            f"database (the figure compares {algo_label(pair[0])} against {algo_label(pair[1])}; "
            "--pair A,B compares two it holds)"
        )
    if ev.empty:
        what = f" for {', '.join(algo_label(a) for a in algos)}" if algos else data.what()
        raise ReportError(f"figure {number}: no evaluation episodes{what} in the database")
    refs = simple_policy_references(sort_regimes(ev["regime"]), episodes=reference_episodes, log=log)
    return eval_across_regimes(
        data.eval,
        algos=algos,
        references=refs,
        title=pair_title(pair, ablation) if number == 4 else "Fixed-policy inference across regimes",
        colors=data.colors,
        day_references=_day_references(data, log),
        labels=ablation_labels(ablation),
    )


def build_figure(
    number: int,
    data: ReportData,
    reference_episodes: int = 200,
    log: Log | None = None,
    pair: Sequence[str] = DEFAULT_PAIR,
    ablation: dict[str, str] | None = None,
) -> FigureResult:
    """Figure 1-4 of the paper from ``data`` (Figure 4: ``pair``, which ``data`` must hold, and
    beside it ``ablation``'s configs, each a pair config without memory:
    :func:`without_memory`); :class:`ReportError` when it has nothing to draw."""
    try:
        if number in (1, 2):
            train = data.rows("train", f"figure {number}")
            # the dashed "best" line marks the best return (Figure 1); most foods eaten is no "best"
            res = training_curves(
                train, "return" if number == 1 else "foods", best_line=number == 1, colors=data.colors
            )
        elif number in (3, 4):
            res = _eval_figure(number, data, pair, reference_episodes, log, ablation)
        elif number == 6:
            raise ReportError(
                "figure 6 is read from the database: build_report(db, figs=[6]) or learning_figure(db, data)"
            )
        elif number == 5:
            from nutribench.report.aggregate_view import aggregate_figure

            agg = _aggregate(data, "figure 5")
            headroom = aggregate_points(data.eval, _day_references(data), agg.regimes)
            res = aggregate_figure(agg, data.colors, ev=data.eval, headroom=headroom)
        else:
            raise ReportError(f"no figure {number}: the figures are {', '.join(map(str, FIGURES))}")
    except ValueError as e:
        if isinstance(e, ReportError):
            raise
        raise ReportError(f"figure {number}: {e}") from None
    # what load_report_data left out (older versions, smaller budgets) goes on the figure too
    return _add_notes(res, data.notes)


def learning_figure(db: DbFile, data: ReportData | None, algos: Sequence[str] | None = None) -> FigureResult:
    """Figure 6: the learning curves of the evaluations during training stored in ``db``
    (:mod:`nutribench.report.learning`), in ``data``'s colours; :class:`ReportError` without any."""
    from nutribench.report.learning import learning_curve_figure
    from nutribench.store import read_learning_curve

    try:
        return learning_curve_figure(read_learning_curve(db), data.colors if data else None, algos)
    except ValueError as e:
        raise ReportError(f"figure 6: {e}") from None


def _day_references(data: ReportData, log: Log | None = None):
    """The never/planner yardsticks on every evaluation day of ``data`` (Figures 3/4 panel (A),
    the results table, Figure 5), played once per ``data``."""
    if getattr(data, "_day_references", None) is None:
        data._day_references = eval_day_references(data.eval, log=log)  # type: ignore[attr-defined]
    return data._day_references  # type: ignore[attr-defined]


def _aggregate(data: ReportData, what: str):
    """The aggregate scores of ``data``'s evaluation episodes (Figure 5 and the aggregate
    table), computed once per ``data``."""
    from nutribench.report.aggregate import aggregate_from_eval

    if getattr(data, "_aggregate", None) is None:
        data._aggregate = aggregate_from_eval(data.rows("eval", what), _day_references(data))  # type: ignore[attr-defined]
    return data._aggregate  # type: ignore[attr-defined]


def _metrics_table(key: str, data: ReportData | None) -> TableResult:
    """The results, the training or the aggregate table of ``data``."""
    if data is None:
        raise ReportError(f"the {key} table needs the episode metrics of the database")
    if key == "aggregate":
        from nutribench.report.aggregate_view import aggregate_table

        return aggregate_table(_aggregate(data, "aggregate table"), data.eval).add_notes(data.notes)
    if key == "results":
        return table_results(data.rows("eval", "results table"), references=_day_references(data)).add_notes(data.notes)
    return table_training(data.rows("train", "training table")).add_notes(data.notes)


def build_table(
    key: str, data: ReportData | None = None, db: DbFile | None = None, stored: dict[str, Any] | None = None
) -> TableResult:
    """Table ``key``: "1" from the regime files; "2".."6" from the built-in agent config files
    (else the newest config of that name stored in ``db``); "7"... (or a config's name) from
    the configs stored in ``db`` (``stored``: :func:`stored_agent_configs`, read when not
    given); "results" and "training" from the episodes of ``data``."""
    key = str(key)
    if key == "1":
        names = list_regimes()
        if not names:
            raise ReportError("table 1: no regime files found")
        return table_regimes([load_env_config(n) for n in names])
    if key in ("results", "training", "aggregate"):
        return _metrics_table(key, data)
    if stored is None and key not in TABLES:
        stored = stored_or_none(db)
    numbers = config_table_numbers(stored or ())
    number = int(resolve_table(key, numbers)[0])
    return config_table(number, numbers[number], db, stored)


def _page_subtitle(db: DbFile, data: ReportData | None) -> str:
    """index.html's line under the title: the database's name (never the folder it lay in,
    which may be a temporary one) and the budgets and seeds of what the page draws."""
    from sqlalchemy.engine import make_url

    text = str(db)
    name = Path(text).name if "://" not in text else Path(make_url(text).database or "").name
    parts = [f"from {name}"] if name else []
    if data is not None and not data.eval.empty:
        parts.append(budget_caption(data.eval))
    return "; ".join(parts)


def _request(db: DbFile, figs, tables, all: bool, algos, pair) -> tuple[list[int], list[str], tuple[str, str], Any]:  # noqa: A002
    """:func:`build_report`'s figures, tables and pair, checked, and the database's stored agent
    configs where they are needed (else None); :class:`ReportError` for what cannot be asked."""
    figs = list(FIGURES) if all else [int(f) for f in figs]
    tables = [str(t) for t in tables]
    for f in figs:
        if f not in FIGURES:
            raise ReportError(f"no figure {f}: the figures are {', '.join(map(str, FIGURES))}")
    if not figs and not tables:
        raise ReportError("nothing to build: ask for figures, tables or all")
    pair_given, pair = pair is not None, check_pair(pair, DEFAULT_PAIR)
    stored = stored_agent_configs(db) if needs_stored_configs(figs, tables, all, algos) else None
    if stored is not None and algos is not None:
        check_known(algos, stored, "--algos")
    if stored is not None and pair_given and 4 in figs:
        check_known(pair, stored, "--pair")
    return figs, tables, pair, stored


class _Writer:
    """Writes a report's items as they are built, each announced (``progress``: ``[k/n] what``),
    and keeps what index.html shows; with ``all``, an item the data cannot give is skipped
    (one ``skipped:`` line through ``log``) instead of failing the report."""

    def __init__(self, out: DbFile, steps: int, all: bool, log: Log, progress: Log | None) -> None:  # noqa: A002
        self.out, self.steps, self.all, self.log, self.progress = out, steps, all, log, progress
        self.done = 0
        self.paths: list[Path] = []
        self.page: list[Any] = []

    def item(self, what: str, make: Callable[[], Any], stem: str, number: int | None = None) -> None:
        """Build (``make``) and write one figure (``number``) or table (file stem ``stem``)."""
        self.done += 1
        if self.progress and self.steps > 1:  # one item: its own line (or error) says it all
            self.progress(f"[{self.done}/{self.steps}] {what}")
        try:
            res = make()
        except ReportError as e:
            if not self.all:
                raise
            self.log(f"skipped: {e}")
            return
        figure = number is not None
        written = (write_figure if figure else write_table)(res, self.out, stem)
        self.page.append(page_figure(number, res, written) if figure else page_table(stem, res, written))
        self.paths += written


def build_report(
    db: DbFile,
    out: DbFile = "reports",
    figs: Iterable[int] = (),
    tables: Iterable[str | int] = (),
    all: bool = False,  # noqa: A002 - mirrors the --all option
    reference_episodes: int = 200,
    log: Log | None = None,
    algos: Sequence[str] | None = None,
    pair: Sequence[str] | None = None,
    progress: Log | None = None,
) -> list[Path]:
    """Write the requested figures and tables under ``out`` and return the paths written.

    ``all=True`` builds Figures 1-6, Table 1, the config tables of the agents the database
    holds results of, the results, the training and the aggregate tables, and ``index.html``:
    those figures and tables on one static page (:mod:`nutribench.report.html`); what the
    database cannot support (Figure 4 without results of both PPO and GRU-PPO, Figure 6
    without evaluations during training, the table of a config without results) is skipped,
    each with one line through ``log``: ``skipped: <item>: <why>``. An item asked for by number that cannot be built
    raises :class:`ReportError`. ``algos``: the agent configs drawn (default: every config in
    the database); ``pair``: Figure 4's two configs (default PPO and GRU-PPO; not limited by
    ``algos``; beside them the database's copies of them without memory); a name the database
    does not hold raises :class:`ReportError`.
    ``reference_episodes``: episodes per simple policy and regime for the reference lines of
    Figures 3/4. ``progress``: called with ``[k/n] figure 3`` (or ``table results``) as each
    item starts, so a long ``--all`` shows where it is.
    """
    figs, tables, pair, stored = _request(db, figs, tables, all, algos, pair)
    log = log or quiet
    plan = table_plan(tables, all, stored, algos)
    # the database is read once, up front, and only when something needs it: a database that
    # cannot be read (missing, empty, outdated) fails the whole command, even with ``all``
    raw = read_metrics(db) if figs or {"results", "training", "aggregate"} & set(plan) else None
    data = prepare(raw, algos) if raw is not None else None
    if all and raw is not None:
        for key, why in unheld_tables(plan, stored, raw, tables).items():
            del plan[key]
            log(f"skipped: {why}")
    ablation = without_memory(pair, stored, raw) if 4 in figs else {}
    pair_data = prepare(raw, [*pair, *ablation]) if raw is not None and 4 in figs else None
    for note in dict.fromkeys([*(data.notes if data else []), *(pair_data.notes if pair_data else [])]):
        log(f"note: {note}")
    w = _Writer(out, len(figs) + len(plan) + int(all), all, log, progress)
    for f in figs:
        figure_data = pair_data if f == 4 else data
        make = partial(build_figure, f, figure_data, reference_episodes, log, pair, ablation)
        w.item(f"figure {f}", partial(learning_figure, db, data, algos) if f == 6 else make, figure_stem(f, pair), f)
    for key, stem in plan.items():
        w.item(f"table {key}", partial(build_table, key, data, db, stored), stem)
    if all and data is not None and not data.eval.empty:
        # the leaderboard section of index.html: every entry (name, version, budget) of the configs
        # the report draws, as ``nutribench leaderboard`` ranks them, none hidden by another (the
        # figures' choice of the newest version and largest budget is not the leaderboard's)
        from nutribench.report.leaderboard import leaderboard_from_db

        w.item("leaderboard", partial(leaderboard_from_db, db, log=log, algos=data.selected), "leaderboard")
    if all:
        w.paths.append(write_index(w.page, out, title="nutribench report", subtitle=_page_subtitle(db, data)))
    return w.paths


__all__ = [
    "FIGURES",
    "TABLES",
    "ReportData",
    "ReportError",
    "build_figure",
    "build_report",
    "build_table",
    "build_trajectory",
    "check_known",
    "check_names",
    "eval_day_references",
    "figure_stem",
    "load_report_data",
    "prepare",
    "read_metrics",
    "resolve_table",
    "simple_policy_references",
    "stored_agent_configs",
    "write_figure",
    "write_table",
]
