"""Absorption kernels: pure numpy, computed once per regime.

A food consumed at step t with mean delay ``tau`` and spread ``sigma`` (steps) delivers its
amount over steps u = t+1 .. t+ceil(6 sigma) with weights
``exp(-0.5 ((u - (t + tau)) / sigma) ** 2)`` normalised to sum to 1 over that window.
With sigma = 0 the whole amount arrives at step t + round(tau) (round half up), which is
the same step t when tau = 0.

Kernels are indexed by the offset k = u - t >= 0.
"""

from __future__ import annotations

import math

import numpy as np


def kernel(tau: float, sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """Offsets k (steps after consumption) and weights (summing to 1) of one kernel."""
    if sigma < 0 or tau < 0:
        raise ValueError(f"tau and sigma must be >= 0, got tau={tau}, sigma={sigma}")
    if sigma == 0:
        return np.array([int(math.floor(tau + 0.5))]), np.ones(1)  # round half up
    offsets = np.arange(1, math.ceil(6 * sigma) + 1)
    with np.errstate(over="ignore"):
        logw = -0.5 * ((offsets - tau) / sigma) ** 2
    if np.isfinite(logw.max()):
        # Subtracting the max before exp changes nothing after normalisation but keeps a
        # window far from tau (all weights tiny) from underflowing to 0/0.
        w = np.exp(logw - logw.max())
    else:  # sigma so small that every weight overflows: the limit puts all on the nearest offset(s)
        dist = np.abs(offsets - tau)
        w = (dist == dist.min()).astype(np.float64)
    return offsets, w / w.sum()


def absorption_schedule(masses: np.ndarray, tau: np.ndarray, sigma: np.ndarray, length: int) -> np.ndarray:
    """``A[i, k, n]``: amount of nutrient n of food i absorbed k steps after eating it.

    Offsets at or beyond ``length`` are dropped: with ``length = horizon`` that is exactly
    what can never arrive within an episode (eaten at step t >= 1, arriving after step H).
    """
    n_foods, n_nut = masses.shape
    A = np.zeros((n_foods, length, n_nut))
    for i in range(n_foods):
        for n in range(n_nut):
            offsets, w = kernel(float(tau[i, n]), float(sigma[i, n]))
            keep = offsets < length
            A[i, offsets[keep], n] = masses[i, n] * w[keep]
    return A


def arrivals_by_horizon(schedule: np.ndarray, horizon: int) -> np.ndarray:
    """``R[t, i, n]``: amount of nutrient n of food i that arrives by step H when eaten after
    t steps have been taken (i.e. at step t + 1). Used by the planner."""
    cums = np.cumsum(schedule, axis=1)  # (N, L, 3): arrived within offsets 0..k
    # R[t] = cums[:, H - t - 1]: eaten at step t+1, offsets up to H-(t+1)
    return np.ascontiguousarray(cums[:, horizon - 1 :: -1, :].transpose(1, 0, 2))
