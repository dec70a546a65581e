"""Table builders: Table 1 from the regime files, Tables 2-6 from the five built-in agent
config files, Tables 7, 8, ... from the other agent configs (variants, plug-in agents) stored in
the database, and the results table from the episode metrics. Each returns a :class:`TableResult` with the raw
numbers (written as CSV) and a formatted frame (written as Markdown and LaTeX). The training
table sets beside ours the training results the paper's authors logged
(:data:`AUTHORS_LAST_10PCT`)."""

from __future__ import annotations

import itertools
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass

import numpy as np
import pandas as pd

from nutribench.agents.registry import names
from nutribench.baselines import gap_closed
from nutribench.report.figure_parts import budget_caption, budget_cell, sort_regimes
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos
from nutribench.stats import caption as interval_caption
from nutribench.stats import iqm_runs_ci, mean_ci, sem

RESULT_METRICS = ["return", "final_distance", "foods", "overshoot_ratio"]
#: Tables 2..6 of the paper, in order.
CONFIG_TABLES = {2: "mc", 3: "ddqn", 4: "ppo", 5: "sac", 6: "gru_ppo"}
#: The number of the first table of a config other than the five.
FIRST_OTHER_TABLE = 7


def config_table_numbers(names: Iterable[str]) -> dict[int, str]:
    """Table number -> config name: 2-6 for the five built-in configs, then 7, 8, ... for the
    other ``names`` sorted by name (so the numbers follow from the set of configs alone)."""
    others = sorted(set(names) - set(CONFIG_TABLES.values()))
    return {**CONFIG_TABLES, **{FIRST_OTHER_TABLE + i: n for i, n in enumerate(others)}}


def markdown_rows(frame: pd.DataFrame) -> list[str]:
    """``frame`` as the lines of a Markdown table, every cell as it is (no padding: a row of
    the table reads ``| 1 | GRU-PPO | 68 [59, 75] |``, as the committed reports hold them)."""
    cols = list(frame.columns)
    rows = ["| " + " | ".join(str(v) for v in row) + " |" for row in frame.itertuples(index=False)]
    return ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols), *rows]


#: How a table's LaTeX float is placed and ruled.
_FLOAT = dict(position="t", position_float="centering", hrules=True)


@dataclass
class TableResult:
    name: str
    title: str
    raw: pd.DataFrame
    formatted: pd.DataFrame

    def add_notes(self, notes: list[str]) -> TableResult:
        """The table with ``notes`` (what was left out of its data) at the end of its caption."""
        if notes:
            self.title += " (note: " + "; ".join(notes) + ")"
        return self

    def to_markdown(self) -> str:
        return "\n".join([f"**{self.title}**", "", *markdown_rows(self.formatted)]) + "\n"

    def to_latex(self) -> str:
        """The table as a LaTeX ``table`` float (booktabs rules), every text escaped
        (:func:`latex_escape`), written by pandas' Styler."""
        style = self.formatted.style.hide(axis="index").format(latex_escape).format_index(latex_escape, axis=1)
        return style.to_latex(
            caption=latex_escape(self.title), column_format="l" * len(self.formatted.columns), **_FLOAT
        )

    def to_csv(self) -> str:
        return self.raw.to_csv(index=False)


#: LaTeX's special characters and what each becomes in running text.
_LATEX_SPECIAL = {
    **{ch: "\\" + ch for ch in "&%$#_{}"},
    "\\": r"\textbackslash{}",
    "~": r"\textasciitilde{}",
    "^": r"\textasciicircum{}",
    "±": r"$\pm$",
}


def latex_escape(value: object) -> str:
    """``value`` as LaTeX text: every special character escaped, character by character."""
    return "".join(_LATEX_SPECIAL.get(ch, ch) for ch in str(value))


#: Table 1's range columns, in the paper's order.
_RANGES = list(itertools.product(("tau", "sigma"), ("C", "P", "F")))


def table_regimes(configs) -> TableResult:
    """Table 1: the delay regimes (ranges in steps), from the regime files."""
    rows = []
    for cfg in configs:
        r = cfg.regime.ranges
        row = {"run": cfg.name, "description": cfg.regime.description, "version": cfg.version, "seed": cfg.regime.seed}
        for what, n in _RANGES:
            rng_ = getattr(getattr(r, what), n)
            row[f"{what}_{n}_low"], row[f"{what}_{n}_high"] = rng_.low, rng_.high
        rows.append(row)
    raw = pd.DataFrame(rows)
    raw = raw.set_index("run").loc[sort_regimes(raw["run"])].reset_index()
    fmt = pd.DataFrame({"run": raw["run"], "description": raw["description"]})
    for what, n in _RANGES:
        lo, hi = raw[f"{what}_{n}_low"], raw[f"{what}_{n}_high"]
        fmt[f"{what}_{n}"] = [f"{a:g}" if a == b else f"{a:g}-{b:g}" for a, b in zip(lo, hi)]
    return TableResult(
        "table1", "Table 1: delay regimes (steps; per-food values drawn uniformly from these ranges)", raw, fmt
    )


def _flatten(d: dict, prefix: str = "") -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict) and v:
            out.update(_flatten(v, f"{prefix}{k}."))
        else:  # an empty table (e.g. [params]) is still shown
            out[f"{prefix}{k}"] = "{}" if isinstance(v, dict) else v
    return out


def _config_title(number: int, name: str, content: dict) -> str:
    """``Table 4: PPO configuration (ppo v1)``; a variant or plug-in says its algorithm."""
    algo = content.get("algo", name)
    # an algorithm without a builder of its own (algo "external") is a plug-in named by its entry point
    kind = "" if algo == name else f", {algo_label(algo)} variant" if algo in names() else ", external agent"
    entry = f" {content['entry_point']}" if content.get("entry_point") else ""
    if algo == "external" and not content.get("entry_point"):
        entry = ", recorded: trained by its own loop, so only what it declared"
    return f"Table {number}: {algo_label(name)} configuration ({name} v{content.get('version')}{kind}{entry})"


#: What ``nutribench run`` reads of an external config to train its plug-in: a recorded loop
#: (no entry point) never declared or used them.
RUNNER_SETTINGS = ("entry_point", "params", "normalize_obs", "normalize_reward", "gamma")


def declared(content: dict) -> dict:
    """The keys of a stored config body that were declared: all of them, but for a recorded
    agent (``algo = "external"`` without an entry point: :class:`nutribench.Recorder`,
    ``nutribench evaluate``), whose stored body also holds the runner's defaults
    (``entry_point None``, ``normalize_obs False``, ``gamma 0.99``, empty ``params``), those
    of :data:`RUNNER_SETTINGS` still at their defaults are left out."""
    if content.get("algo") != "external" or content.get("entry_point") is not None:
        return content
    from nutribench.agents.builtin.external import ExternalConfig

    fields = ExternalConfig.model_fields
    default = {k: fields[k].get_default(call_default_factory=True) for k in RUNNER_SETTINGS if k in fields}
    return {k: v for k, v in content.items() if not (k in default and v == default[k])}


def table_agent_config(number: int, config) -> TableResult:
    """Tables 2-6 (and 7, ...): every declared key of one agent config (a model from its file,
    or the body stored in the database; :func:`declared`); nested tables such as an external
    agent's ``[params]`` as ``params.<key>`` rows."""
    content = declared(config.model_dump(mode="json"))
    flat = _flatten(content)
    raw = pd.DataFrame(
        {"hyperparameter": list(flat), "value": [v if not isinstance(v, list) else str(v) for v in flat.values()]}
    )
    fmt = raw.assign(value=[", ".join(map(str, v)) if isinstance(v, list) else str(v) for v in flat.values()])
    return TableResult(f"table{number}", _config_title(number, config.name, content), raw, fmt)


def mean_sem_cell(values: pd.Series, digits: int) -> tuple[float, float, str]:
    """Mean, standard error, and the table's text ``mean ± se`` (the mean alone for one value,
    ``n/a`` for none)."""
    if values.empty:  # a job with no training day in its window yet (still running): said, not averaged
        return float("nan"), float("nan"), "n/a"
    mean, se = float(np.mean(values.to_numpy(dtype=float))), sem(values)
    return mean, se, f"{mean:.{digits}f} ± {se:.{digits}f}" if np.isfinite(se) else f"{mean:.{digits}f}"


def interval_cell(point: float, lo: float, hi: float, fmt: Callable[[float], str] = "{:.2f}".format) -> str:
    """A table's ``point [lo, hi]`` (each written by ``fmt``); ``point [single seed]`` without an
    interval, ``n/a`` without a point."""
    if not np.isfinite(point):
        return "n/a"
    return f"{fmt(point)} [{fmt(lo)}, {fmt(hi)}]" if np.isfinite(lo) else f"{fmt(point)} [single seed]"


def table_results(df: pd.DataFrame, references: pd.DataFrame | None = None) -> TableResult:
    """Results: regime x algorithm. It leads with the seed-level interval: the mean over seeds
    of each seed's mean return over its evaluation days, with its 95 % interval over seeds
    (:func:`nutribench.stats.mean_ci`) (raw ``return_seed_mean``, ``return_seed_lo``, ``return_seed_hi``);
    then, for comparison with the paper, mean ± standard error of the four evaluation metrics
    over seeds x evaluation episodes pooled, and the interquartile mean over seeds of each
    seed's mean return with its trimmed-t interval (:func:`nutribench.stats.iqm_runs_ci`, the
    IQM interval the statistics module chose; raw ``return_iqm``, ``return_iqm_lo``,
    ``return_iqm_hi``).

    With ``references`` (columns regime, seed, episode, never, planner: the two yardsticks'
    returns on each evaluation day) each row also gives the mean return of ``never`` and of
    the ``planner`` on exactly the row's evaluation days, and the share of that gap the
    agent closes; NaN where a day of the row has no reference. Where ``references`` also has
    ``lookahead`` and ``clairvoyant`` (:mod:`nutribench.report.references`), each row gives their
    shares of the same gap on the same days (``lookahead_gap``, ``clairvoyant_gap``): the
    headroom above the planner's 100 %."""
    ev = df[df["phase"] == "eval"]
    if ev.empty:
        raise ValueError("no evaluation episodes for the results table")
    strong = references is not None and {"lookahead", "clairvoyant"} <= set(references.columns)
    yard = ["never", "planner", "lookahead", "clairvoyant"] if strong else ["never", "planner"]
    ref = references.set_index(["regime", "seed", "episode"])[yard] if references is not None else None
    rows = [_result_row(regime, algo, cell, ref, strong) for regime, algo, cell in _cells(ev)]
    title = (
        "Results: fixed-policy inference; first the seed-level 95 % interval (mean over seeds of each seed's mean over its "
        f"evaluation days, {interval_caption('mean')}), then mean ± standard error over seeds x evaluation "
        "episodes pooled (as the paper reports) and the IQM over seeds of each seed's mean return "
        f"({interval_caption('iqm')}); {budget_caption(ev)}"
    )
    if strong:
        from nutribench.report.references import SOURCE

        title += (
            "; lookahead / clairvoyant: the shares of the same gap the two references above the planner close on the "
            f"row's days (100 % is the greedy planner, not the optimum; {SOURCE})"
        )
    return TableResult("results", title, *_frames(rows))


def _frames(rows: list[tuple[dict, dict]]) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The raw and the formatted frame of a table's (raw row, formatted row) pairs."""
    return pd.DataFrame([r for r, _ in rows]), pd.DataFrame([f for _, f in rows])


def _cells(df: pd.DataFrame) -> Iterator[tuple[str, str, pd.DataFrame]]:
    """(regime, algo, rows) of each regime (in order) and agent (in palette order) of ``df``."""
    for regime in sort_regimes(df["regime"]):
        for algo in sort_algos(df[df["regime"] == regime]["algo"]):
            yield regime, algo, df[(df["regime"] == regime) & (df["algo"] == algo)]


def _result_row(
    regime: str, algo: str, cell: pd.DataFrame, ref: pd.DataFrame | None, strong: bool
) -> tuple[dict, dict]:
    """The results table's raw and formatted row of one agent on one regime: with the
    yardsticks ``ref``, their cells (:func:`_yardstick_cells`; the gap's interval keeps its
    column's place) and, ``strong``, the references above the planner (:func:`_strong_cells`);
    the raw row holds the seed-level interval and the budget last."""
    row = {"regime": regime, "algo": algo, "seeds": cell["seed"].nunique(), "episodes": len(cell)}
    f = {"regime": regime, "algorithm": algo_label(algo), "budget (days)": budget_cell(cell)}
    f.update(seeds=row["seeds"], episodes=row["episodes"])
    seed_means = cell.groupby("seed")["return"].mean().to_numpy(dtype=float)
    seed_ci = mean_ci(seed_means)
    f["return [95% CI over seeds]"] = interval_cell(*seed_ci)
    if ref is not None:
        f["gap closed [95% CI over seeds]"] = "n/a"
    for m in RESULT_METRICS:
        row[f"{m}_mean"], row[f"{m}_sem"], f[m] = mean_sem_cell(cell[m], 2 if m in ("return", "foods") else 3)
    point, lo, hi = iqm_runs_ci([seed_means])
    row["return_iqm"], row["return_iqm_lo"], row["return_iqm_hi"] = point, lo, hi
    f["return IQM [95% CI over seeds]"] = interval_cell(point, lo, hi)
    days = _yardstick_cells(row, f, cell, ref) if ref is not None else None
    row["return_seed_mean"], row["return_seed_lo"], row["return_seed_hi"] = seed_ci
    row["budget"] = f["budget (days)"]  # last: the CSV's earlier columns keep their places
    if strong:
        _strong_cells(row, f, days)
    return row, f


def _yardstick_cells(row: dict, f: dict, cell: pd.DataFrame, ref: pd.DataFrame) -> pd.DataFrame | None:
    """Never's and the planner's mean returns on the row's days and the share of their gap the
    agent closes, raw and formatted; the days' yardsticks (None where one lacks a day)."""
    days = ref.reindex(pd.MultiIndex.from_arrays([cell["regime"], cell["seed"], cell["episode"]]))
    complete = not days[["never", "planner"]].isna().any().any()
    for p in ("never", "planner"):
        row[f"{p}_mean"] = float(days[p].mean()) if complete else float("nan")
    row["gap_closed"] = gap_closed(row["return_mean"], row["never_mean"], row["planner_mean"]) if complete else np.nan
    f["never / planner"] = f"{row['never_mean']:.2f} / {row['planner_mean']:.2f}" if complete else "n/a"
    f["gap closed"] = f"{100 * row['gap_closed']:.0f} %" if np.isfinite(row["gap_closed"]) else "n/a"
    shares = _seed_shares(cell, days) if complete else np.array([])
    gap_ci = mean_ci(shares) if shares.size and np.isfinite(shares).all() else (np.nan,) * 3
    row["gap_closed_seed_mean"], row["gap_closed_seed_lo"], row["gap_closed_seed_hi"] = gap_ci
    f["gap closed [95% CI over seeds]"] = interval_cell(*gap_ci, lambda v: f"{100 * v:.0f} %")
    return days if complete else None


def _strong_cells(row: dict, f: dict, days: pd.DataFrame | None) -> None:
    """The lookahead's and the clairvoyant's shares of the gap on the row's days (``days``:
    their yardsticks; None where never/planner lack a day), raw and formatted."""
    cells = []
    for p in ("lookahead", "clairvoyant"):
        v = float("nan")
        if days is not None and not days[p].isna().any():
            v = gap_closed(float(days[p].mean()), row["never_mean"], row["planner_mean"])
        row[f"{p}_gap"] = v
        cells.append(f"{100 * v:.0f} %" if np.isfinite(v) else "n/a")
    f["lookahead / clairvoyant"] = " / ".join(cells)


def _seed_shares(cell: pd.DataFrame, days: pd.DataFrame) -> np.ndarray:
    """Each seed's share of the never -> planner gap closed on its own evaluation days
    (``days``: the yardsticks of ``cell``'s rows, in the same order)."""
    frame = days[["never", "planner"]].astype(float).reset_index(drop=True)
    frame = frame.assign(seed=cell["seed"].to_numpy(), ret=cell["return"].to_numpy(dtype=float))
    means = frame.groupby("seed")[["ret", "never", "planner"]].mean()
    return np.array([gap_closed(r, n, p) for r, n, p in means.itertuples(index=False)], dtype=float)


#: The regimes of the authors' figures, in order.
AUTHORS_REGIMES = ("run0", "run1", "run2", "run3", "run4", "run5", "run6")
#: The authors' figures: the training results logged by the paper's authors, read from the
#: ``results/Training/*.csv`` files of their public repository
#: (<https://github.com/CharithaPalika/NutriRL>): ``return_mean`` and ``foods_mean`` averaged
#: over the last 10 % of their 5000 training days. Their returns are in their own units
#: (nutrients divided by their catalog's column norms, overshoot weight 0 in the published
#: runs), where never eating scores about -21.5 a day; ours (reward version 2) give never
#: -21.6, so the two scales are comparable but not identical (our own yardsticks are in
#: :mod:`nutribench.report.references`). algo -> (return, foods) per regime, run0..run6.
AUTHORS_LAST_10PCT: dict[str, tuple[tuple[float, float], ...]] = {
    "mc": ((-7.1, 4.8), (-8.4, 4.6), (-8.2, 4.6), (-9.8, 4.5), (-9.1, 4.8), (-11.6, 4.9), (-10.7, 5.6)),
    "ddqn": ((-10.1, 2.2), (-10.3, 2.6), (-11.2, 2.4), (-20.9, 0.3), (-13.2, 2.2), (-27.9, 13.4), (-17.8, 7.4)),
    "ppo": ((-5.9, 5.0), (-8.2, 5.1), (-8.6, 5.3), (-11.9, 7.7), (-8.8, 5.3), (-15.6, 9.8), (-12.6, 8.9)),
    "sac": ((-8.2, 5.6), (-38.9, 25.5), (-34.1, 22.1), (-35.8, 25.5), (-34.6, 25.7), (-31.0, 25.5), (-29.0, 25.3)),
    "gru_ppo": ((-5.9, 5.0), (-7.6, 4.7), (-7.0, 4.8), (-8.7, 4.8), (-8.1, 5.2), (-9.9, 5.5), (-10.4, 6.4)),
}
AUTHORS_BUDGET = 5000


def authors_training(algo: str, regime: str) -> tuple[float, float] | None:
    """The authors' (return, foods) of the last 10 % of training days, or None if not logged."""
    if algo not in AUTHORS_LAST_10PCT or regime not in AUTHORS_REGIMES:
        return None
    return AUTHORS_LAST_10PCT[algo][AUTHORS_REGIMES.index(regime)]


def table_training(df: pd.DataFrame, last_share: float = 0.1) -> TableResult:
    """Our training return and foods over the last ``last_share`` of each job's training days
    (mean over days and seeds, with the seeds' spread as a standard error), next to the
    authors' logged ones over the last 10 % of their 5000 days
    (:data:`AUTHORS_LAST_10PCT`)."""
    tr = df[df["phase"] == "train"]
    if tr.empty:
        raise ValueError("no training episodes for the training table")
    rows = []
    for regime, algo, cell in _cells(tr):
        budget = int(cell["budget"].max())
        # days are numbered from 0: the window always holds the last day (a 1- or 5-day job has one)
        tail = cell[cell["episode"] >= min(budget * (1 - last_share), budget - 1)]
        per_seed = tail.groupby("seed")[["return", "foods"]].mean()
        theirs = authors_training(algo, regime)
        row = {"regime": regime, "algo": algo, "days": budget, "seeds": len(per_seed)}
        f = {"regime": regime, "algorithm": algo_label(algo), "our days": budget, "seeds": len(per_seed)}
        for m in ("return", "foods"):
            row[f"{m}_mean"], row[f"{m}_sem"], f[f"our {m}"] = mean_sem_cell(per_seed[m], 2)
            row[f"authors_{m}"] = float("nan") if theirs is None else theirs[0 if m == "return" else 1]
            f[f"authors' {m}"] = "" if theirs is None else f"{row[f'authors_{m}']:.1f}"
        rows.append((row, f))
    pct = round(100 * last_share)
    title = (
        f"Training: mean return and foods per day over the last {pct} % of training days, ours (± standard error over "
        f"seeds) and the authors' logged ones (last 10 % of their {AUTHORS_BUDGET} days)"
    )
    return TableResult("training", title, *_frames(rows))
