"""Summary statistics used by the figures and tables: standard errors, IQM, bootstrap CIs."""

from __future__ import annotations

import numpy as np
import pandas as pd


def sem(values: np.ndarray | pd.Series) -> float:
    """Standard error of the mean (sample std / sqrt(n)); NaN for fewer than 2 values."""
    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return float("nan")
    return float(x.std(ddof=1) / np.sqrt(x.size))


def mean_sem(df: pd.DataFrame, by: list[str], value: str) -> pd.DataFrame:
    """Mean, standard error and count of ``value`` per group of ``by``."""
    g = df.groupby(by, observed=True)[value]
    out = g.agg(["mean", "count"]).reset_index()
    out["sem"] = g.apply(lambda s: sem(s.to_numpy())).to_numpy()
    return out


def iqm(values: np.ndarray) -> float:
    """Interquartile mean: the mean of the middle 50 % of the values (rliable's IQM)."""
    x = np.sort(np.asarray(values, dtype=float))
    n = x.size
    if n == 0:
        return float("nan")
    lo, hi = int(np.floor(0.25 * n)), int(np.ceil(0.75 * n))
    if hi <= lo:  # fewer than 4 values: IQM is the plain mean
        return float(x.mean())
    return float(x[lo:hi].mean())


def iqm_bootstrap_ci(
    values_by_seed: list[np.ndarray], reps: int = 2000, alpha: float = 0.05, seed: int = 0
) -> tuple[float, float, float]:
    """IQM of all values and a percentile bootstrap CI resampling *seeds* (runs) with
    replacement, as rliable recommends for few-seed RL results. With one seed the interval
    is (nan, nan): a single run gives no spread to resample."""
    pooled = np.concatenate(values_by_seed) if values_by_seed else np.array([])
    point = iqm(pooled)
    if len(values_by_seed) < 2:
        return point, float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    k = len(values_by_seed)
    stats = np.empty(reps)
    for r in range(reps):
        pick = rng.integers(0, k, size=k)
        stats[r] = iqm(np.concatenate([values_by_seed[i] for i in pick]))
    lo, hi = np.quantile(stats, [alpha / 2, 1 - alpha / 2])
    return point, float(lo), float(hi)


def seed_mean_ci(
    seed_means: np.ndarray | list[float], reps: int = 2000, alpha: float = 0.05, seed: int = 0
) -> tuple[float, float, float]:
    """Mean of the seeds' means and its percentile bootstrap interval over **seeds**: each
    resample redraws the seeds with replacement (each seed's mean over its evaluation days is
    one value), as for few-seed RL results (Agarwal et al. 2021). ``(mean, nan, nan)`` with
    fewer than two seeds: one run gives no spread to resample."""
    x = np.asarray(seed_means, dtype=float)
    x = x[np.isfinite(x)]
    if x.size == 0:
        return float("nan"), float("nan"), float("nan")
    point = float(x.mean())
    if x.size < 2:
        return point, float("nan"), float("nan")
    rng = np.random.default_rng(seed)
    stats = x[rng.integers(0, x.size, size=(reps, x.size))].mean(axis=1)
    lo, hi = np.quantile(stats, [alpha / 2, 1 - alpha / 2])
    return point, float(lo), float(hi)
