"""Performance profiles and the probability of improvement of run scores
(:mod:`nutribench.report.scores`), as Agarwal et al. (NeurIPS 2021) recommend and ``rliable``
computes, each with a band or interval from :mod:`nutribench.stats`, made without resamples
(no printed digit depends on a seed):

* the performance profile: the fraction of runs whose score exceeds tau (rliable's score
  distribution), with a t band per tau (:func:`nutribench.stats.strata_t`: the fraction is the
  mean of the runs' indicators, its standard error taken within each regime), clipped to [0, 1];
* the probability of improvement P(X > Y) for every pair: per regime the probability that a
  run of X scores above a run of Y (a tie counts half: the Mann-Whitney U over the product of
  the run counts), averaged over regimes, with a t interval from DeLong's variance of each
  regime's share (:func:`nutribench.stats.improvement_ci`).

Their coverage, measured by ``benchmarks/coverage.py``: :data:`nutribench.stats.COVERAGE`.
"""

from __future__ import annotations

from collections.abc import Iterable

import numpy as np
import pandas as pd
from rliable import metrics as rly

from nutribench.report.scores import DEFAULT_REPS, GAMMA, ScoreSet
from nutribench.stats import CONFIDENCE, Runs, improvement_ci, strata_t


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
