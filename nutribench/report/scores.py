"""Run scores and their stratified bootstrap: what the aggregate statistics, the performance
profiles and the probabilities of improvement (:mod:`nutribench.report.aggregate`) are
computed from.

A **run** is one job: an agent config trained with one seed on one regime. Its **score** is
the share of the regime's never -> planner gap it closes on its own evaluation days,
``(mean return - mean never) / (mean planner - mean never)`` over those days (0 = never eat,
1 = the greedy full-information planner, more than 1 possible; the results table's "gap
closed", per seed). The regimes are rliable's *tasks*, the seeds its *runs*.

The bootstrap is a **stratified bootstrap over runs**: every resample redraws, within each
regime, that regime's seeds with replacement (rliable's ``StratifiedBootstrap``,
``task_bootstrap=False``), vectorised over resamples; it is drawn by
:func:`nutribench.stats.stratified_resamples`, the one module that draws resamples.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from nutribench.baselines import gap_closed
from nutribench.report.figure_parts import sort_regimes
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos
from nutribench.stats import CONFIDENCE, Runs, percentile_interval, seeded_rng, stratified_resamples

#: The optimality gap's threshold: the planner's score.
GAMMA = 1.0
#: Bootstrap resamples (rliable uses 50000 for its published figures; 2000 keeps a report fast).
DEFAULT_REPS = 2000

__all__ = [
    "CONFIDENCE",
    "DEFAULT_REPS",
    "GAMMA",
    "Runs",
    "ScoreSet",
    "percentile_interval",
    "pooled",
    "run_scores",
    "score_set",
    "seeded_rng",
    "stratified_resamples",
]


def run_scores(ev: pd.DataFrame, references: pd.DataFrame) -> pd.DataFrame:
    """One row per run (regime, algo, seed) of the evaluation episodes ``ev``: its days, its
    mean return, the mean return of ``never`` and of the ``planner`` on the same days, and its
    score (the share of that gap it closes; NaN where a day has no yardstick).

    ``references``: columns regime, seed, episode, never, planner
    (:func:`nutribench.report.references.eval_day_references`). ``ev`` must hold one job per
    run (:func:`nutribench.report.build.prepare` picks them); several raise ValueError.
    """
    ev = ev[ev["phase"] == "eval"] if "phase" in ev else ev
    cols = ["regime", "algo", "seed", "days", "return", "never", "planner", "score"]
    if ev.empty:
        return pd.DataFrame(columns=cols)
    if "job_id" in ev and (ev.groupby(["regime", "algo", "seed"])["job_id"].nunique() > 1).any():
        raise ValueError("several jobs for one regime/algo/seed: pick one per run first (report.build.prepare)")
    ref = references.set_index(["regime", "seed", "episode"])[["never", "planner"]]
    rows = []
    for (regime, algo, seed), days in ev.groupby(["regime", "algo", "seed"], sort=True):
        yard = ref.reindex(pd.MultiIndex.from_arrays([days["regime"], days["seed"], days["episode"]]))
        complete = not yard.isna().any().any()
        ret = float(days["return"].mean())
        never = float(yard["never"].mean()) if complete else float("nan")
        planner = float(yard["planner"].mean()) if complete else float("nan")
        score = gap_closed(ret, never, planner) if complete else float("nan")
        rows.append((regime, algo, int(seed), len(days), ret, never, planner, score))
    return pd.DataFrame(rows, columns=cols)


@dataclass
class ScoreSet:
    """The run scores of one group of regimes: per agent, one array per regime (seed order)."""

    regimes: list[str]
    runs: dict[str, Runs]
    notes: list[str] = field(default_factory=list)


def score_set(
    scores: pd.DataFrame, regimes: Iterable[str], algos: Sequence[str] | None = None, what: str = ""
) -> ScoreSet:
    """The scores of ``algos`` (default every agent of ``scores``) on those of ``regimes`` that
    every one of them has a score on; a regime left out is named in a note (``what``: the
    group's name, for the note)."""
    algos = sort_algos(scores["algo"]) if algos is None else list(algos)
    finite = scores[np.isfinite(scores["score"].to_numpy(dtype=float))]
    by = {key: g.sort_values("seed")["score"].to_numpy(dtype=float) for key, g in finite.groupby(["regime", "algo"])}
    ran = set(zip(scores["regime"], scores["algo"]))
    kept, notes = [], []
    for regime in sort_regimes(set(regimes) & set(scores["regime"])):
        lacking = [a for a in algos if (regime, a) not in by]
        missing = [algo_label(a) for a in lacking if (regime, a) not in ran]
        unscored = [algo_label(a) for a in lacking if (regime, a) in ran]
        why = []
        if missing:
            why.append(f"no evaluation of {', '.join(missing)}")
        if unscored:
            why.append(
                f"no never/planner yardstick on the days of {', '.join(unscored)}: the regime file is not the version the jobs ran"
            )
        if why:
            notes.append(f"{what + ': ' if what else ''}{regime} left out ({'; '.join(why)})")
        else:
            kept.append(regime)
    return ScoreSet(kept, {a: [by[(r, a)] for r in kept] for a in algos}, notes)


# Each statistic of the bootstrap takes one array per regime, shaped (resamples, runs of that
# regime), and returns one value per resample; on the original sample (one "resample") it
# equals rliable's. The resampling itself is nutribench.stats's.
def pooled(t: Runs) -> np.ndarray:
    """Every regime's runs side by side: shape (resamples, all runs)."""
    return np.concatenate(t, axis=1)
