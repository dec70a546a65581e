"""Aggregate scores over regimes and seeds, as Agarwal et al. (NeurIPS 2021, "Deep RL at the
Edge of the Statistical Precipice") recommend and their library ``rliable`` computes.

The scores are run scores (:mod:`nutribench.report.scores`: one per job, the share of the
regime's never -> planner gap it closes on its evaluation days). Per agent and per group of
regimes (``all``; ``delayed``: run1-run6):

* the IQM (interquartile mean of all run scores), the median and the mean of the per-regime
  mean scores, and the optimality gap (``1 - mean(min(score, 1))``: how far below the planner,
  lower is better), each with a 95 % interval made without resamples (no digit depends on a
  seed): the IQM's from :func:`nutribench.stats.iqm_runs_ci` (the trimmed t, its standard error
  stratified by regime: the coverage simulation's choice, docs/statistics.md), the median's
  from :func:`nutribench.stats.median_of_means_ci`, the mean's and the optimality gap's from
  :func:`nutribench.stats.strata_t` (t intervals, standard errors within regimes);
* the performance profile and the probability of improvement P(X > Y) for every pair, each
  with a band or interval from :mod:`nutribench.stats`, made without resamples (no printed
  digit depends on a seed): the performance profile is the fraction of runs whose score
  exceeds tau (rliable's score distribution), with a t band per tau
  (:func:`nutribench.stats.strata_t`: the fraction is the mean of the runs' indicators, its
  standard error taken within each regime), clipped to [0, 1]; the probability of
  improvement P(X > Y) is, per regime, the probability that a run of X scores above a run of
  Y (a tie counts half: the Mann-Whitney U over the product of the run counts), averaged
  over regimes, with a t interval from DeLong's variance of each regime's share
  (:func:`nutribench.stats.improvement_ci`). Their coverage, measured by
  ``benchmarks/coverage.py``: :data:`nutribench.stats.COVERAGE`.

Why rliable is used this way (pyproject.toml; the documentation's "Seed-level statistics"):
rliable 1.2.0 needs ``arch < 8`` for its bootstrap (``rliable.library``), and arch 7.2 fails
at import under pandas 3 (arch 8 rejects the ``random_state=None`` rliable passes). The point
estimates here come from ``rliable.metrics`` (numpy/scipy only, imports fine), called on the
regimes x seeds matrix whenever every regime has the same number of seeds; the intervals are
:mod:`nutribench.stats`'s (its percentile bootstrap, :data:`BATCHED` over
:func:`~nutribench.stats.stratified_resamples`, equals rliable's: tests/test_statistics.py,
though no table prints it now). With different seed counts per regime rliable has
no matrix to take; the same statistics are then computed on the ragged runs (IQM and
optimality gap over all runs pooled, mean and median over the regimes' means).

Everything is DataFrame in, DataFrame out: :func:`run_scores` (episodes -> scores),
:func:`aggregate_scores` (scores -> :class:`AggregateResult`); the figure and the table of a
result: :mod:`nutribench.report.aggregate_view`. The names of :mod:`~nutribench.report.scores`
are importable from here too.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
from rliable import metrics as rly

from nutribench.report.figure_parts import regime_index, sort_regimes
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos
from nutribench.report.scores import DEFAULT_REPS, GAMMA, ScoreSet, pooled, run_scores, score_set
from nutribench.stats import (
    CONFIDENCE,
    Runs,
    improvement_ci,
    iqm,
    iqm_runs_ci,
    median_of_means_ci,
    percentile_interval,
    strata_t,
    stratified_resamples,
)

#: The delayed regimes of the paper (run0 has no delays).
DELAYED_REGIMES: tuple[str, ...] = tuple(f"run{i}" for i in range(1, 7))
#: The groups of regimes aggregated over, and how figures and tables name them.
GROUPS: dict[str, str] = {"all": "all regimes", "delayed": "delayed regimes (run1-run6)"}
#: The aggregates, in the figure's and the table's order.
AGGREGATES: tuple[str, ...] = ("iqm", "median", "mean", "optimality_gap")
AGGREGATE_LABELS: dict[str, str] = {a: a.replace("_", " ") for a in AGGREGATES} | {"iqm": "IQM"}


# --------------------------------------------------------------------------- interval estimates
# Each statistic takes one array per regime, shaped (resamples, runs of that regime), and
# returns one value per resample; on the original sample (one "resample") it equals rliable's.
def _task_means(t: Runs) -> np.ndarray:
    return np.stack([x.mean(axis=1) for x in t], axis=1)


BATCHED: dict[str, Callable[[Runs], np.ndarray]] = {
    "iqm": lambda t: iqm(pooled(t), axis=1),
    "median": lambda t: np.median(_task_means(t), axis=1),
    "mean": lambda t: np.mean(_task_means(t), axis=1),
    "optimality_gap": lambda t: GAMMA - np.mean(np.minimum(pooled(t), GAMMA), axis=1),
}
#: rliable's own estimators, on a (runs x regimes) matrix.
RLIABLE: dict[str, Callable[[np.ndarray], float]] = {
    "iqm": rly.aggregate_iqm,
    "median": rly.aggregate_median,
    "mean": rly.aggregate_mean,
    "optimality_gap": lambda m: rly.aggregate_optimality_gap(m, gamma=GAMMA),
}


def point_estimate(aggregate: str, runs: Runs) -> float:
    """``aggregate`` of the run scores (one array per regime): rliable's estimator when every
    regime has the same number of runs, else the same statistic on the ragged runs."""
    if len({len(x) for x in runs}) == 1:
        return float(RLIABLE[aggregate](np.stack(runs, axis=1)))
    return float(BATCHED[aggregate]([x[None, :] for x in runs])[0])


def interval_estimates(
    ss: ScoreSet, reps: int = DEFAULT_REPS, seed: int = 0, confidence: float = CONFIDENCE
) -> pd.DataFrame:
    """Per agent and aggregate: the point estimate and its 95 % interval over runs (NaN with
    one run per regime everywhere: nothing to vary), each from :mod:`nutribench.stats`
    without resamples: the IQM's :func:`~nutribench.stats.iqm_runs_ci` (the trimmed t the
    coverage simulation chose), the median's :func:`~nutribench.stats.median_of_means_ci`
    (each regime's mean as a t variable), the mean's and the optimality gap's
    :func:`~nutribench.stats.strata_t` (the regimes' means weighed alike; every run alike,
    scores capped at the planner's), each standard error taken within regimes. ``reps`` and
    ``seed`` are kept for callers: no interval here draws a resample, so none depends on a seed.

    Columns: algo, aggregate, point, lo, hi, runs, regimes."""
    rows = []
    for algo, runs in ss.runs.items():
        if not runs:
            continue
        spread = max(len(x) for x in runs) > 1
        sizes = [len(x) for x in runs]
        values = np.concatenate(runs)
        for agg in AGGREGATES:
            if not spread:
                lo, hi = float("nan"), float("nan")
            elif agg == "iqm":
                lo, hi = iqm_runs_ci(runs, confidence)[1:]
            elif agg == "median":
                lo, hi = median_of_means_ci(runs, confidence)[1:]
            elif agg == "mean":
                lo, hi = (float(v[0]) for v in strata_t(values, sizes, "regime", confidence)[1:])
            else:  # the gap falls as the capped mean rises
                _, capped_lo, capped_hi = strata_t(np.minimum(values, GAMMA), sizes, "run", confidence)
                lo, hi = GAMMA - float(capped_hi[0]), GAMMA - float(capped_lo[0])
            rows.append((algo, agg, point_estimate(agg, runs), lo, hi, int(sum(sizes)), len(runs)))
    return pd.DataFrame(rows, columns=["algo", "aggregate", "point", "lo", "hi", "runs", "regimes"])


# --------------------------------------------------------------------------- profiles and P(X > Y)
def profile_taus(scores: Iterable[float], n: int = 201) -> np.ndarray:
    """The thresholds of a performance profile: from below the lowest score (and 0) to above
    the highest (and 1), so every profile runs from 1 down to 0."""
    s = np.asarray(list(scores), dtype=float)
    s = s[np.isfinite(s)]
    lo = min(0.0, float(s.min())) if s.size else 0.0
    hi = max(GAMMA, float(s.max())) if s.size else GAMMA
    pad = 0.02 * (hi - lo)
    return np.linspace(lo - pad, hi + pad, n)


def score_distribution(scores: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """The fraction of runs (the last axis of ``scores``) scoring above each tau (rliable's
    ``score_distributions``): shape ``scores.shape[:-1] + (len(taus),)``."""
    return np.mean(scores[..., :, None] > taus, axis=-2)


def performance_profiles(
    ss: ScoreSet, taus: np.ndarray, reps: int = DEFAULT_REPS, seed: int = 0, confidence: float = CONFIDENCE
) -> pd.DataFrame:
    """Per agent and tau: the fraction of its runs scoring above tau, with its 95 % t band
    over runs (:func:`nutribench.stats.strata_t` of the indicators, standard error within
    regimes; no band with one run per regime). ``reps``, ``seed``: kept for callers, unused.
    Columns: algo, tau, fraction, lo, hi."""
    frames = []
    for algo, runs in ss.runs.items():
        if not runs:
            continue
        point = score_distribution(np.concatenate(runs), taus)
        if max(len(x) for x in runs) > 1:
            above = (np.concatenate(runs)[None, :] > taus[:, None]).astype(float)  # (taus, runs)
            _, lo, hi = strata_t(above, [len(x) for x in runs], "run", confidence)
            lo, hi = np.clip(lo, 0.0, 1.0), np.clip(hi, 0.0, 1.0)
        else:
            lo = hi = np.full_like(point, np.nan)
        frames.append(pd.DataFrame({"algo": algo, "tau": taus, "fraction": point, "lo": lo, "hi": hi}))
    empty = pd.DataFrame(columns=["algo", "tau", "fraction", "lo", "hi"])
    return pd.concat(frames, ignore_index=True) if frames else empty


def probability_of_improvement(x: Runs, y: Runs) -> float:
    """rliable's average probability of improvement of X over Y (its own function when both
    have the same number of runs on every regime; else the same statistic on the ragged runs:
    per regime the share of (run of X, run of Y) pairs where X scores higher, ties half,
    averaged over regimes)."""
    if len({len(a) for a in x}) == 1 and len({len(b) for b in y}) == 1:
        return float(rly.probability_of_improvement(np.stack(x, axis=1), np.stack(y, axis=1)))
    return float(np.mean([np.mean((a[:, None] > b) + 0.5 * (a[:, None] == b)) for a, b in zip(x, y)]))


def improvement_probabilities(
    ss: ScoreSet, reps: int = DEFAULT_REPS, seed: int = 0, confidence: float = CONFIDENCE
) -> pd.DataFrame:
    """P(X > Y) with its 95 % interval (:func:`nutribench.stats.improvement_ci`) for every
    ordered pair of agents. ``reps``, ``seed``: kept for callers, unused. Columns: x, y, p, lo, hi."""
    algos = [a for a, runs in ss.runs.items() if runs]
    rows = []
    for i, a in enumerate(algos):
        for b in algos[i + 1 :]:
            x, y = ss.runs[a], ss.runs[b]
            p = probability_of_improvement(x, y)
            lo, hi = improvement_ci(x, y, confidence)[1:]
            rows += [
                {"x": a, "y": b, "p": p, "lo": lo, "hi": hi},
                {"x": b, "y": a, "p": 1 - p, "lo": 1 - hi, "hi": 1 - lo},
            ]
    return pd.DataFrame(rows, columns=["x", "y", "p", "lo", "hi"])


# --------------------------------------------------------------------------- all of it
@dataclass
class AggregateResult:
    """The aggregates of one set of run scores, per group of regimes (:data:`GROUPS`)."""

    scores: pd.DataFrame  # run_scores
    #: group -> the regimes aggregated over (every agent has a score on each)
    regimes: dict[str, list[str]]
    intervals: pd.DataFrame  # group, algo, aggregate, point, lo, hi, runs, regimes
    profiles: pd.DataFrame  # group, algo, tau, fraction, lo, hi
    improvement: pd.DataFrame  # group, x, y, p, lo, hi
    algos: list[str]
    reps: int
    #: group -> agent -> its own regimes, for an agent that lacks regimes the others have: it is
    #: aggregated over its own (its rows in ``intervals``), apart from the others
    partial: dict[str, dict[str, list[str]]] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)


def group_regimes(regimes: Iterable[str]) -> dict[str, list[str]]:
    """The regimes of each group among ``regimes``: ``all`` of them, the ``delayed`` ones."""
    regimes = sort_regimes(regimes)
    return {"all": regimes, "delayed": [r for r in regimes if r in DELAYED_REGIMES]}


def aggregate_scores(
    scores: pd.DataFrame,
    reps: int = DEFAULT_REPS,
    seed: int = 0,
    algos: Sequence[str] | None = None,
    groups: Mapping[str, Iterable[str]] | None = None,
) -> AggregateResult:
    """Interval estimates, performance profiles and probabilities of improvement of the run
    scores (:func:`run_scores`) of ``algos`` (default: every agent of ``scores``), for each
    group of regimes (default :func:`group_regimes`). Deterministic for a given ``seed``."""
    algos = sort_algos(scores["algo"]) if algos is None else list(algos)
    groups = {k: list(v) for k, v in (groups or group_regimes(scores["regime"])).items()}
    notes: list[str] = []
    used: dict[str, list[str]] = {}
    intervals, profiles, improvement = [], [], []
    taus = profile_taus(scores["score"])
    partial: dict[str, dict[str, list[str]]] = {}
    for group, regimes in groups.items():
        full, short = _full_and_partial(scores, regimes, algos)
        ss = score_set(scores, regimes, full)
        notes += ss.notes  # a regime left out is named once, whichever groups it is in
        used[group] = ss.regimes
        if not ss.regimes and regimes and full:
            notes.append(f"{GROUPS.get(group, group)}: no regime with a score for every agent, nothing to aggregate")
        if ss.regimes:
            intervals.append(interval_estimates(ss, reps, seed).assign(group=group))
            profiles.append(performance_profiles(ss, taus, reps, seed).assign(group=group))
            improvement.append(improvement_probabilities(ss, reps, seed).assign(group=group))
        for algo in short:  # over its own regimes, apart: it never shrinks the others' regimes
            own = score_set(scores, regimes, [algo])
            if own.regimes:
                partial.setdefault(group, {})[algo] = own.regimes
                intervals.append(interval_estimates(own, reps, seed).assign(group=group))

    def frame(parts: list[pd.DataFrame], cols: list[str]) -> pd.DataFrame:
        out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=[c for c in cols if c != "group"])
        return out.reindex(columns=cols)

    for algo in [a for a in algos if any(a in by for by in partial.values())]:
        spans = "; ".join(
            f"{GROUPS.get(g, g).split(' (')[0]}: {regime_span(by[algo])}" for g, by in partial.items() if algo in by
        )
        notes.append(
            f"{algo_label(algo)} lacks regimes the others have: aggregated over its own ({spans}), "
            "not comparable with the others' aggregates nor in their profiles and P(X > Y)"
        )
    frames = (  # the fields intervals, profiles and improvement, in that order
        frame(intervals, ["group", "algo", "aggregate", "point", "lo", "hi", "runs", "regimes"]),
        frame(profiles, ["group", "algo", "tau", "fraction", "lo", "hi"]),
        frame(improvement, ["group", "x", "y", "p", "lo", "hi"]),
    )
    return AggregateResult(scores, used, *frames, algos, reps, partial, list(dict.fromkeys(notes)))


def _full_and_partial(scores: pd.DataFrame, regimes: Iterable[str], algos: Sequence[str]) -> tuple[list, list]:
    """The agents with a score on every one of ``regimes`` that any agent has one on, and the
    others (a recorded agent run on one regime, say), in ``algos``' order."""
    finite = scores[np.isfinite(scores["score"].to_numpy(dtype=float)) & scores["regime"].isin(list(regimes))]
    have = finite.groupby("algo")["regime"].agg(set).to_dict()
    wanted = set().union(*have.values()) if have else set()
    full = [a for a in algos if have.get(a, set()) >= wanted]
    return full, [a for a in algos if a not in full and have.get(a)]


def aggregate_from_eval(
    ev: pd.DataFrame, references: pd.DataFrame, reps: int = DEFAULT_REPS, seed: int = 0
) -> AggregateResult:
    """:func:`aggregate_scores` of the evaluation episodes ``ev`` (one job per run) scored
    against ``references`` (:func:`nutribench.report.references.eval_day_references`)."""
    return aggregate_scores(run_scores(ev, references), reps=reps, seed=seed, algos=sort_algos(ev["algo"]))


def regime_span(regimes: Sequence[str]) -> str:
    """``run0-run6`` for consecutive runs, else the names (``run1, run3``)."""
    idx = [regime_index(r) for r in regimes]
    if len(regimes) > 2 and None not in idx and idx == list(range(idx[0], idx[0] + len(idx))):
        return f"{regimes[0]}-{regimes[-1]}"
    return ", ".join(regimes)


def group_title(res: AggregateResult, group: str, algo: str | None = None) -> str:
    """``all regimes (run0-run6)``, ``delayed regimes (run1-run6)``, or with the regimes
    actually aggregated over where some were left out (``delayed regimes (run1, run3)``); for an
    ``algo`` aggregated over its own regimes (:attr:`AggregateResult.partial`), those, marked
    (``all regimes (run3 only: this agent's)``)."""
    own = res.partial.get(group, {}).get(algo) if algo is not None else None
    if own:
        return f"{GROUPS.get(group, group).split(' (')[0]} ({regime_span(own)} only: this agent's)"
    regimes = res.regimes.get(group, [])
    name = GROUPS.get(group, group).split(" (")[0]
    return f"{name} ({regime_span(regimes)})" if regimes else name


__all__ = [
    "AGGREGATES",
    "AGGREGATE_LABELS",
    "BATCHED",
    "CONFIDENCE",
    "DEFAULT_REPS",
    "DELAYED_REGIMES",
    "GAMMA",
    "GROUPS",
    "RLIABLE",
    "AggregateResult",
    "ScoreSet",
    "aggregate_from_eval",
    "aggregate_scores",
    "group_regimes",
    "group_title",
    "improvement_probabilities",
    "interval_estimates",
    "percentile_interval",
    "performance_profiles",
    "point_estimate",
    "probability_of_improvement",
    "profile_taus",
    "regime_span",
    "run_scores",
    "score_distribution",
    "score_set",
    "stratified_resamples",
]
