"""Aggregate scores over regimes and seeds, as Agarwal et al. (NeurIPS 2021, "Deep RL at the
Edge of the Statistical Precipice") recommend and their library ``rliable`` computes.

A **run** is one job: an agent config trained with one seed on one regime. Its **score** is
the share of the regime's never -> planner gap it closes on its own evaluation days,
``(mean return - mean never) / (mean planner - mean never)`` over those days (0 = never eat,
1 = the greedy full-information planner, more than 1 possible; the results table's "gap
closed", per seed). The regimes are rliable's *tasks*, the seeds its *runs*.

Per agent and per group of regimes (``all``; ``delayed``: run1-run6):

* the IQM (interquartile mean of all run scores), the median and the mean of the per-regime
  mean scores, and the optimality gap (``1 - mean(min(score, 1))``: how far below the planner,
  lower is better), each with a 95 % percentile interval from a **stratified bootstrap over
  runs**: every resample redraws, within each regime, that regime's seeds with replacement
  (rliable's ``StratifiedBootstrap``, ``task_bootstrap=False``);
* the performance profile: the fraction of runs whose score exceeds tau, with a band from the
  same bootstrap (rliable's score distribution);
* the probability of improvement P(X > Y) for every pair: per regime the probability that a
  run of X scores above a run of Y (a tie counts half: the Mann-Whitney U over the product of
  the run counts), averaged over regimes, with an interval from rliable's
  ``StratifiedIndependentBootstrap`` (X's and Y's runs redrawn independently per regime).

Why rliable is used this way (pyproject.toml, README "Figures and tables"): rliable 1.2.0
needs ``arch < 8`` for its bootstrap (``rliable.library``), and arch 7.2 fails at import under
pandas 3 (arch 8 rejects the ``random_state=None`` rliable passes). The point estimates here
come from ``rliable.metrics`` (numpy/scipy only, imports fine), called on the regimes x seeds
matrix whenever every regime has the same number of seeds; the bootstrap is the small
resampling loop below, vectorised over resamples, whose statistics equal rliable's on the
original sample (tests/test_statistics.py). With different seed counts per regime rliable
has no matrix to take; the same statistics are then computed on the ragged runs (IQM and
optimality gap over all runs pooled, mean and median over the regimes' means).

Everything is DataFrame in, DataFrame out: :func:`run_scores` (episodes -> scores),
:func:`aggregate_scores` (scores -> :class:`AggregateResult`); the figure and the table of a
result: :mod:`nutribench.report.aggregate_view`.

Longer than 400 lines: since ruff formats it (one argument per line); the estimators and
their bootstrap belong together. To split: the performance profiles and probability of improvement.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd
import scipy.stats
from rliable import metrics as rly

from nutribench.baselines import gap_closed
from nutribench.report.figures import sort_regimes
from nutribench.report.palette import label as algo_label
from nutribench.report.palette import order as sort_algos

#: The delayed regimes of the paper (run0 has no delays).
DELAYED_REGIMES: tuple[str, ...] = tuple(f"run{i}" for i in range(1, 7))
#: The groups of regimes aggregated over, and how figures and tables name them.
GROUPS: dict[str, str] = {"all": "all regimes", "delayed": "delayed regimes (run1-run6)"}
#: The aggregates, in the figure's and the table's order.
AGGREGATES: tuple[str, ...] = ("iqm", "median", "mean", "optimality_gap")
AGGREGATE_LABELS: dict[str, str] = {
    "iqm": "IQM",
    "median": "median",
    "mean": "mean",
    "optimality_gap": "optimality gap",
}
#: The optimality gap's threshold: the planner's score.
GAMMA = 1.0
#: Bootstrap resamples (rliable uses 50000 for its published figures; 2000 keeps a report fast).
DEFAULT_REPS = 2000
CONFIDENCE = 0.95

Runs = list[np.ndarray]  # one array of run scores per regime (task)


# --------------------------------------------------------------------------- scores
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
        rows.append(
            {
                "regime": regime,
                "algo": algo,
                "seed": int(seed),
                "days": len(days),
                "return": ret,
                "never": never,
                "planner": planner,
                "score": score,
            }
        )
    return pd.DataFrame(rows, columns=cols)


@dataclass
class ScoreSet:
    """The run scores of one group of regimes: per agent, one array per regime (seed order)."""

    regimes: list[str]
    runs: dict[str, Runs]
    notes: list[str] = field(default_factory=list)

    def rectangular(self, algo: str) -> bool:
        """Whether ``algo`` has the same number of runs on every regime (an rliable matrix)."""
        return len({len(x) for x in self.runs[algo]}) == 1

    def matrix(self, algo: str) -> np.ndarray:
        """``algo``'s scores as rliable takes them: ``(runs, regimes)`` (rectangular only)."""
        return np.stack(self.runs[algo], axis=1)


def score_set(
    scores: pd.DataFrame, regimes: Iterable[str], algos: Sequence[str] | None = None, what: str = ""
) -> ScoreSet:
    """The scores of ``algos`` (default every agent of ``scores``) on those of ``regimes`` that
    every one of them has a score on; a regime left out is named in a note (``what``: the
    group's name, for the note)."""
    algos = sort_algos(scores["algo"]) if algos is None else list(algos)
    finite = scores[np.isfinite(scores["score"].to_numpy(dtype=float))]
    kept, notes = [], []
    for regime in sort_regimes(set(regimes) & set(scores["regime"])):
        missing, unscored = [], []
        for algo in algos:
            if finite[(finite["regime"] == regime) & (finite["algo"] == algo)].empty:
                ran = not scores[(scores["regime"] == regime) & (scores["algo"] == algo)].empty
                (unscored if ran else missing).append(algo_label(algo))
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
    runs = {
        a: [
            finite[(finite["regime"] == r) & (finite["algo"] == a)].sort_values("seed")["score"].to_numpy(dtype=float)
            for r in kept
        ]
        for a in algos
    }
    return ScoreSet(kept, runs, notes)


# --------------------------------------------------------------------------- statistics
# Each statistic takes one array per regime, shaped (resamples, runs of that regime), and
# returns one value per resample; on the original sample (one "resample") it equals rliable's.
def _pooled(t: Runs) -> np.ndarray:
    return np.concatenate(t, axis=1)


def _task_means(t: Runs) -> np.ndarray:
    return np.stack([x.mean(axis=1) for x in t], axis=1)


BATCHED: dict[str, Callable[[Runs], np.ndarray]] = {
    "iqm": lambda t: scipy.stats.trim_mean(_pooled(t), proportiontocut=0.25, axis=1),
    "median": lambda t: np.median(_task_means(t), axis=1),
    "mean": lambda t: np.mean(_task_means(t), axis=1),
    "optimality_gap": lambda t: GAMMA - np.mean(np.minimum(_pooled(t), GAMMA), axis=1),
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


def stratified_resamples(runs: Runs, reps: int, rng: np.random.Generator) -> Runs:
    """``reps`` stratified bootstrap resamples of the runs: within each regime, that regime's
    runs drawn with replacement (as many as it has), regimes independently; one array
    ``(reps, runs)`` per regime (rliable's ``StratifiedBootstrap`` over runs)."""
    return [x[rng.integers(0, len(x), size=(reps, len(x)))] for x in runs]


def percentile_interval(values: np.ndarray, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """The percentile bootstrap interval (arch's ``method="percentile"``, rliable's default)."""
    alpha = (1 - confidence) / 2
    lo, hi = np.percentile(values, [100 * alpha, 100 * (1 - alpha)], axis=0)
    return float(lo), float(hi)


def _rng(seed: int, *names: str) -> np.random.Generator:
    """A generator per (seed, names): an agent's intervals do not depend on the other agents."""
    return np.random.default_rng([seed, *(zlib.crc32(n.encode()) for n in names)])


def interval_estimates(
    ss: ScoreSet, reps: int = DEFAULT_REPS, seed: int = 0, confidence: float = CONFIDENCE
) -> pd.DataFrame:
    """Per agent and aggregate: the point estimate and its stratified-bootstrap interval over
    runs (NaN with one run per regime everywhere: nothing to resample).

    Columns: algo, aggregate, point, lo, hi, runs, regimes."""
    rows = []
    for algo, runs in ss.runs.items():
        if not runs:
            continue
        resampled = stratified_resamples(runs, reps, _rng(seed, algo, *ss.regimes))
        spread = max(len(x) for x in runs) > 1
        for agg in AGGREGATES:
            lo, hi = (
                percentile_interval(BATCHED[agg](resampled), confidence) if spread else (float("nan"), float("nan"))
            )
            rows.append(
                {
                    "algo": algo,
                    "aggregate": agg,
                    "point": point_estimate(agg, runs),
                    "lo": lo,
                    "hi": hi,
                    "runs": int(sum(len(x) for x in runs)),
                    "regimes": len(runs),
                }
            )
    return pd.DataFrame(rows, columns=["algo", "aggregate", "point", "lo", "hi", "runs", "regimes"])


def profile_taus(scores: Iterable[float], n: int = 201) -> np.ndarray:
    """The thresholds of a performance profile: from below the lowest score (and 0) to above
    the highest (and 1), so every profile runs from 1 down to 0."""
    s = np.asarray(list(scores), dtype=float)
    s = s[np.isfinite(s)]
    lo = min(0.0, float(s.min())) if s.size else 0.0
    hi = max(GAMMA, float(s.max())) if s.size else GAMMA
    pad = 0.02 * (hi - lo)
    return np.linspace(lo - pad, hi + pad, n)


def score_distribution(pooled: np.ndarray, taus: np.ndarray) -> np.ndarray:
    """The fraction of runs (the last axis of ``pooled``) scoring above each tau (rliable's
    ``score_distributions``): shape ``pooled.shape[:-1] + (len(taus),)``."""
    return np.mean(pooled[..., :, None] > taus, axis=-2)


def performance_profiles(
    ss: ScoreSet, taus: np.ndarray, reps: int = DEFAULT_REPS, seed: int = 0, confidence: float = CONFIDENCE
) -> pd.DataFrame:
    """Per agent and tau: the fraction of its runs scoring above tau, with a stratified
    bootstrap band over runs. Columns: algo, tau, fraction, lo, hi."""
    frames = []
    alpha = (1 - confidence) / 2
    for algo, runs in ss.runs.items():
        if not runs:
            continue
        point = score_distribution(np.concatenate(runs), taus)
        if max(len(x) for x in runs) > 1:
            boot = score_distribution(
                _pooled(stratified_resamples(runs, reps, _rng(seed, "profile", algo, *ss.regimes))), taus
            )
            lo, hi = np.percentile(boot, [100 * alpha, 100 * (1 - alpha)], axis=0)
        else:
            lo = hi = np.full_like(point, np.nan)
        frames.append(pd.DataFrame({"algo": algo, "tau": taus, "fraction": point, "lo": lo, "hi": hi}))
    return (
        pd.concat(frames, ignore_index=True)
        if frames
        else pd.DataFrame(columns=["algo", "tau", "fraction", "lo", "hi"])
    )


def _improvement(x: Runs, y: Runs) -> np.ndarray:
    """P(X > Y) per resample: per regime the share of (run of X, run of Y) pairs where X scores
    higher (ties half), averaged over regimes; ``x``/``y``: one array (resamples, runs) per regime."""
    per_task = [
        np.mean((a[:, :, None] > b[:, None, :]) + 0.5 * (a[:, :, None] == b[:, None, :]), axis=(1, 2))
        for a, b in zip(x, y)
    ]
    return np.mean(np.stack(per_task, axis=1), axis=1)


def probability_of_improvement(x: Runs, y: Runs) -> float:
    """rliable's average probability of improvement of X over Y (its own function when both
    have the same number of runs on every regime)."""
    if len({len(a) for a in x}) == 1 and len({len(b) for b in y}) == 1:
        return float(rly.probability_of_improvement(np.stack(x, axis=1), np.stack(y, axis=1)))
    return float(_improvement([a[None, :] for a in x], [b[None, :] for b in y])[0])


def improvement_probabilities(
    ss: ScoreSet, reps: int = DEFAULT_REPS, seed: int = 0, confidence: float = CONFIDENCE
) -> pd.DataFrame:
    """P(X > Y) with a 95 % interval for every ordered pair of agents (X's and Y's runs
    redrawn independently within each regime). Columns: x, y, p, lo, hi."""
    algos = [a for a, runs in ss.runs.items() if runs]
    rows = []
    for i, a in enumerate(algos):
        for b in algos[i + 1 :]:
            x, y = ss.runs[a], ss.runs[b]
            p = probability_of_improvement(x, y)
            if max(len(r) for r in x + y) > 1:
                rng = _rng(seed, "improvement", a, b, *ss.regimes)
                lo, hi = percentile_interval(
                    _improvement(stratified_resamples(x, reps, rng), stratified_resamples(y, reps, rng)), confidence
                )
            else:
                lo = hi = float("nan")
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
    for group, regimes in groups.items():
        ss = score_set(scores, regimes, algos)
        notes += ss.notes  # a regime left out is named once, whichever groups it is in
        used[group] = ss.regimes
        if not ss.regimes:
            if regimes:
                notes.append(
                    f"{GROUPS.get(group, group)}: no regime with a score for every agent, nothing to aggregate"
                )
            continue
        intervals.append(interval_estimates(ss, reps, seed).assign(group=group))
        profiles.append(performance_profiles(ss, taus, reps, seed).assign(group=group))
        improvement.append(improvement_probabilities(ss, reps, seed).assign(group=group))

    def frame(parts: list[pd.DataFrame], cols: list[str]) -> pd.DataFrame:
        out = pd.concat(parts, ignore_index=True) if parts else pd.DataFrame(columns=[c for c in cols if c != "group"])
        return out.reindex(columns=cols)

    return AggregateResult(
        scores=scores,
        regimes=used,
        algos=algos,
        reps=reps,
        notes=list(dict.fromkeys(notes)),
        intervals=frame(intervals, ["group", "algo", "aggregate", "point", "lo", "hi", "runs", "regimes"]),
        profiles=frame(profiles, ["group", "algo", "tau", "fraction", "lo", "hi"]),
        improvement=frame(improvement, ["group", "x", "y", "p", "lo", "hi"]),
    )


def aggregate_from_eval(
    ev: pd.DataFrame, references: pd.DataFrame, reps: int = DEFAULT_REPS, seed: int = 0
) -> AggregateResult:
    """:func:`aggregate_scores` of the evaluation episodes ``ev`` (one job per run) scored
    against ``references`` (:func:`nutribench.report.references.eval_day_references`)."""
    return aggregate_scores(run_scores(ev, references), reps=reps, seed=seed, algos=sort_algos(ev["algo"]))


def regime_span(regimes: Sequence[str]) -> str:
    """``run0-run6`` for consecutive runs, else the names (``run1, run3``)."""
    from nutribench.report.figures import regime_index

    idx = [regime_index(r) for r in regimes]
    if len(regimes) > 2 and None not in idx and idx == list(range(idx[0], idx[0] + len(idx))):
        return f"{regimes[0]}-{regimes[-1]}"
    return ", ".join(regimes)


def group_title(res: AggregateResult, group: str) -> str:
    """``all regimes (run0-run6)``, ``delayed regimes (run1-run6)``, or with the regimes
    actually aggregated over where some were left out (``delayed regimes (run1, run3)``)."""
    regimes = res.regimes.get(group, [])
    name = GROUPS.get(group, group).split(" (")[0]
    return f"{name} ({regime_span(regimes)})" if regimes else name


__all__ = [
    "AGGREGATES",
    "DELAYED_REGIMES",
    "GROUPS",
    "AggregateResult",
    "ScoreSet",
    "aggregate_from_eval",
    "aggregate_scores",
    "group_regimes",
    "improvement_probabilities",
    "interval_estimates",
    "performance_profiles",
    "point_estimate",
    "probability_of_improvement",
    "run_scores",
    "score_set",
    "stratified_resamples",
]
