"""The cost of a change measured from paired timed runs, with its bootstrap interval: the
statistics of the finished cost studies (``reports/diagnostics_cost``, ``reports/eval_cost``).
Developer code, outside the shipped package; the resamples are drawn by
:func:`nutribench.stats.resample_indices`, as every bootstrap of the project is.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from nutribench.stats import resample_indices


def bootstrap(stat: Callable[..., np.ndarray], arrays: Sequence[np.ndarray], reps: int, seed: int) -> np.ndarray:
    """``stat`` of ``reps`` resamples of paired ``arrays`` (the same indices for each, drawn
    with ``seed``): ``stat(*resampled)`` with each resampled array ``(reps, n)``."""
    idx = resample_indices(len(arrays[0]), reps, np.random.default_rng(seed))
    return stat(*(np.asarray(a, dtype=float)[idx] for a in arrays))


def paired_cost(
    with_: Sequence[float], without: Sequence[float], reps: int = 2000, seed: int = 0
) -> tuple[float, float, float]:
    """The share of time that the difference between paired timed runs takes: ``1 -
    median(without / with)`` over the pairs, with a 95 % percentile bootstrap interval
    resampling the pairs (``reps`` resamples, ``seed``). An interval wider than the cost asked
    of the code says the machine's noise does not resolve it."""
    ratios = np.asarray(without, dtype=float) / np.asarray(with_, dtype=float)
    boot = bootstrap(lambda r: 1 - np.median(r, axis=1), [ratios], reps, seed)
    return 1 - float(np.median(ratios)), float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))


def total_cost(
    with_: Sequence[float], without: Sequence[float], reps: int = 4000, seed: int = 0
) -> tuple[float, float, float]:
    """The share of the total time that the difference takes: ``1 - sum(without) / sum(with)``
    over paired blocks of work, with a 95 % percentile bootstrap interval resampling the pairs
    (``reps`` resamples, ``seed``): each block weighted by its length; the blocks' noise should
    be independent of one another (arms run within seconds of each other)."""
    w, wo = np.asarray(with_, dtype=float), np.asarray(without, dtype=float)
    boot = bootstrap(lambda a, b: 1 - b.sum(axis=1) / a.sum(axis=1), [w, wo], reps, seed)
    return 1 - float(wo.sum() / w.sum()), float(np.percentile(boot, 2.5)), float(np.percentile(boot, 97.5))
