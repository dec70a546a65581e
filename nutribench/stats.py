"""The project's statistics, said once: the IQM, standard errors, the bootstrap (the only code
in ``nutribench/`` that draws bootstrap resamples; ``tests/test_statistics.py`` scans for
others) and the intervals of the three statistics every table prints: a **mean over seeds**,
an **IQM over runs** (stratified by regime) and a **paired difference by seed**.

It sits on the ground floor (it imports nothing of the package) because the report, ``bench``
and the tuning objective all call it, and the tuning objective should not pull in the report.

Intervals: ``"t"`` (Student's t; for the IQM Tukey and McLaughlin's trimmed t: the winsorized
standard error, ``h - 1`` degrees of freedom, :func:`t_intervals`). The coverage simulation of
``benchmarks/coverage.py`` (developer code, outside the package, with the other candidates it
weighed: percentile, BCa and bootstrap-t) chose it for each statistic (:data:`CHOSEN`;
docs/statistics.md, "Intervals and their coverage"); :data:`COVERAGE` is its measured
coverage, quoted in the tables' captions. A bootstrap over one sample of up to
:data:`EXACT_SEEDS` values enumerates every resample (each multiset of draws with its
multinomial probability: 126 at 5 seeds, 92,378 at 10), so its ends do not depend on a seed.

The cost of a change measured from paired timed runs (``paired_cost``, ``total_cost``: the
finished cost studies' of ``reports/``) is developer code: ``benchmarks/cost_stats.py``.

Point estimates are rliable's: the IQM is ``scipy.stats.trim_mean(x, 0.25)``, which
``rliable.metrics.aggregate_iqm`` computes.
"""

from __future__ import annotations

import itertools
import math
import zlib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

CONFIDENCE = 0.95
#: The interval of each statistic, chosen by ``benchmarks/coverage.py`` (docs/statistics.md).
CHOSEN: dict[str, str] = {"mean": "t", "iqm": "t", "paired": "t"}
#: The chosen method's simulated coverage of a nominal 95 % interval at 5 and 10 seeds: the
#: lowest over normal, gamma-skewed and measured scores (``python benchmarks/coverage.py``,
#: 2,000 datasets per cell, seed 0; for the IQM, the lower of one regime and three;
#: docs/statistics.md). ``tests/test_statistics.py`` reruns the simulation (slow) against it.
COVERAGE: dict[str, dict[int, float]] = {
    "mean": {5: 0.950, 10: 0.946},
    "iqm": {5: 0.923, 10: 0.9405},
    "paired": {5: 0.922, 10: 0.941},
}
#: The other aggregates of the report's Figure 5 and aggregate table, which the simulation did
#: not choose a method for: each gets an interval of the chosen t's kind, made without
#: resamples (:func:`median_of_means_ci`, :func:`strata_t`, :func:`improvement_ci`), and
#: their measured coverage, the lowest over normal, gamma-skewed and measured scores over 7
#: regimes (the median's over 7 and 6) at 5 and 10 seeds (``benchmarks/coverage.py``'s second
#: table, 2,000 datasets per cell, seed 0; docs/statistics.md).
AGGREGATE_COVERAGE: dict[str, dict[int, float]] = {
    "median": {5: 0.991, 10: 0.977},
    "mean": {5: 0.946, 10: 0.9485},
    "gap": {5: 0.947, 10: 0.940},
    "profile": {5: 0.957, 10: 0.926},
    "improvement": {5: 0.944, 10: 0.953},
}
#: How a caption names each aggregate's interval (:func:`aggregate_caption`).
AGGREGATE_METHODS: dict[str, str] = {
    "median": "t model of each regime's mean",
    "mean": "t, standard error within regimes",
    "gap": "t, standard error within regimes",
    "profile": "t band of the fraction, standard error within regimes",
    "improvement": "t from DeLong's variance",
}
#: Up to this many values, a one-sample bootstrap enumerates every resample.
EXACT_SEEDS = 10
Runs = list[np.ndarray]  # one array of run scores per regime (stratum)


# --------------------------------------------------------------------------- point estimates
def sem(values) -> float:
    """Standard error of the mean (sample std / sqrt(n)); NaN for fewer than 2 values."""
    x = np.asarray(values, dtype=float)
    if x.size < 2:
        return float("nan")
    return float(x.std(ddof=1) / np.sqrt(x.size))


def iqm(values, axis: int | None = None):
    """Interquartile mean: the mean of the middle 50 % of the values (``int(n / 4)`` cut from
    each end: rliable's IQM, ``scipy.stats.trim_mean(x, 0.25)``); NaN for no values. Over
    ``axis`` of an array, else of every value."""
    from scipy.stats import trim_mean

    x = np.asarray(values, dtype=float)
    if axis is None:
        return float(trim_mean(x.ravel(), 0.25)) if x.size else float("nan")
    return trim_mean(x, 0.25, axis=axis)


def _satterthwaite(terms: Iterable[tuple], fallback: float) -> tuple:
    """The standard error of a sum of independent terms, each given as ``(v_i, d_i)``: its
    variance (a number, or an array of them, alike for every term) estimated with ``d_i``
    degrees of freedom. Returns ``sqrt(sum_i v_i)`` and Welch-Satterthwaite's degrees of
    freedom ``(sum_i v_i)^2 / sum_i (v_i^2 / d_i)``, ``fallback`` where no term has spread.
    Every pooled t interval here takes its degrees of freedom from it (:func:`trimmed_se`,
    :func:`stratified_t`, :func:`strata_t`, :func:`improvement_ci`, :func:`welch_t`)."""
    var = den = 0.0
    for v, d in terms:
        var, den = var + v, den + v**2 / d
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.sqrt(var), np.where(den > 0, var**2 / np.where(den > 0, den, 1), fallback)


def trimmed_se(x: np.ndarray, sizes: Sequence[int] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Tukey and McLaughlin's standard error of the IQM over the last axis and its degrees of
    freedom: the values winsorized at the IQM's cut points, ``sqrt(sum_r n_r s_r^2) / h`` with
    ``s_r`` the winsorized values' standard deviation within stratum ``r`` (``sizes``: the
    strata's consecutive lengths along the axis; default one stratum, where it is the textbook
    ``s_w / ((1 - 2g) sqrt(n))``), ``h`` the values kept, and Welch-Satterthwaite's degrees of
    freedom (``h - 1`` for one stratum). For fewer than 4 values, the mean's."""
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    sizes = [n] if sizes is None else list(sizes)
    cut = int(0.25 * n)
    h = n - 2 * cut
    s = np.sort(x, axis=-1)
    w = np.clip(x, s[..., cut : cut + 1], s[..., n - cut - 1 : n - cut])
    strata = zip(sizes, np.split(w, np.cumsum(sizes), axis=-1))
    terms = [(k * part.var(axis=-1, ddof=1), k - 1) for k, part in strata if k > 1]
    if not terms:
        return np.full(x.shape[:-1], np.nan), np.asarray(np.nan)
    se, df = _satterthwaite(terms, h - 1.0)  # no spread within any regime: a zero-width interval, not NaN
    return se / h, np.asarray(h - 1.0 if len(terms) == 1 else np.minimum(df, h - 1.0))


# --------------------------------------------------------------------------- resampling
def seeded_rng(seed: int, *names: str) -> np.random.Generator:
    """A generator per (seed, names): one agent's intervals do not depend on the others'."""
    return np.random.default_rng([seed, *(zlib.crc32(n.encode()) for n in names)])


def resample_indices(n: int, reps: int, rng: np.random.Generator) -> np.ndarray:
    """``reps`` bootstrap resamples of ``n`` values, as indices drawn with replacement: shape
    ``(reps, n)``. Every bootstrap of the package draws here."""
    return rng.integers(0, n, size=(reps, n))


def stratified_indices(sizes: Sequence[int], reps: int, rng: np.random.Generator) -> list[np.ndarray]:
    """One :func:`resample_indices` per stratum (regime), strata drawn one after the other."""
    return [resample_indices(k, reps, rng) for k in sizes]


def stratified_resamples(runs: Runs, reps: int, rng: np.random.Generator) -> Runs:
    """``reps`` stratified bootstrap resamples of the runs: within each regime, that regime's
    runs drawn with replacement (as many as it has), regimes independently; one array
    ``(reps, runs)`` per regime (rliable's ``StratifiedBootstrap`` over runs)."""
    return [x[i] for x, i in zip(runs, stratified_indices([len(x) for x in runs], reps, rng))]


@lru_cache(maxsize=16)
def _multisets(n: int) -> tuple[np.ndarray, np.ndarray]:
    """Every distinct bootstrap resample of ``n`` values (sorted indices) and its probability."""
    idx = np.array(list(itertools.combinations_with_replacement(range(n), n)))
    counts = np.apply_along_axis(np.bincount, 1, idx, minlength=n)
    logp = math.lgamma(n + 1) - np.vectorize(math.lgamma)(counts + 1.0).sum(axis=1) - n * math.log(n)
    return idx, np.exp(logp)


@dataclass(frozen=True)
class Design:
    """Bootstrap resamples of ``n`` values: indices ``(resamples, n)`` and each one's weight
    (every multiset with its probability when ``exact``, else ``reps`` draws of weight 1/reps)."""

    idx: np.ndarray
    weights: np.ndarray
    exact: bool


def design(n: int, reps: int = 2000, rng: np.random.Generator | None = None, exact: bool | None = None) -> Design:
    """The resamples of one sample of ``n`` values: every one, enumerated, for up to
    :data:`EXACT_SEEDS` values (unless ``exact=False``), else ``reps`` drawn with ``rng``."""
    if exact or (exact is None and n <= EXACT_SEEDS):
        return Design(*_multisets(n), True)
    rng = rng if rng is not None else np.random.default_rng(0)
    return Design(resample_indices(n, reps, rng), np.full(reps, 1.0 / reps), False)


def percentile_interval(values: np.ndarray, confidence: float = CONFIDENCE, weights=None) -> tuple[float, float]:
    """The percentile interval of bootstrap statistics ``values``: numpy's interpolated
    percentiles of drawn resamples (arch's ``method="percentile"``, rliable's default), or with
    ``weights`` (enumerated resamples) the weighted quantiles."""
    alpha = (1 - confidence) / 2
    if weights is None:
        lo, hi = np.percentile(values, [100 * alpha, 100 * (1 - alpha)], axis=0)
        return float(lo), float(hi)
    lo, hi = weighted_quantiles(np.asarray(values)[None, :], np.asarray(weights), np.array([[alpha, 1 - alpha]]))[0]
    return float(lo), float(hi)


def weighted_quantiles(values: np.ndarray, weights: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Per row of ``values`` ``(rows, resamples)`` with resample ``weights``, the quantiles
    ``q`` ``(rows, k)``: the midpoint of the two values where the cumulative weight crosses q
    (the inverse of the bootstrap's distribution function, averaged at a jump's edge)."""
    order = np.argsort(values, axis=1, kind="stable")
    v = np.take_along_axis(values, order, axis=1)
    cw = np.cumsum(weights[order], axis=1)
    cw /= cw[:, -1:]
    out = np.empty(q.shape)
    for j in range(q.shape[1]):
        qj = q[:, j : j + 1]
        lo = np.minimum((cw < qj - 1e-12).sum(axis=1), v.shape[1] - 1)
        hi = np.minimum((cw <= qj + 1e-12).sum(axis=1), v.shape[1] - 1)
        rows = np.arange(v.shape[0])
        out[:, j] = (v[rows, lo] + v[rows, hi]) / 2
    return out


# --------------------------------------------------------------------------- intervals
def _half_width(se, df, confidence: float) -> np.ndarray:
    """Half the width of the two-sided Student's t interval of ``confidence`` about an estimate
    of standard error ``se`` with ``df`` degrees of freedom: every t interval here is one."""
    from scipy.stats import t

    return t.ppf(1 - (1 - confidence) / 2, df) * se


def mean_se(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The standard error of the mean over the last axis and its degrees of freedom (``n - 1``)."""
    n = x.shape[-1]
    return x.std(axis=-1, ddof=1) / np.sqrt(n), np.asarray(n - 1.0)


def t_intervals(
    x: np.ndarray, statistic: str, confidence: float = CONFIDENCE, sizes: Sequence[int] | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """The t interval of ``statistic`` (``"mean"``: Student's t; ``"iqm"``: Tukey and
    McLaughlin's trimmed t, :func:`trimmed_se`) of each row of ``x`` ``(rows, n)``, vectorised
    over rows (the coverage simulation's datasets): ``(lo, hi)``. ``sizes``: strata (regimes)
    of consecutive lengths along a row, for the IQM's standard error."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    if statistic == "iqm":
        theta, (se, df) = iqm(x, axis=-1), trimmed_se(x, sizes)
    else:
        theta, (se, df) = x.mean(axis=-1), mean_se(x)
    half = _half_width(se, df, confidence)
    return theta - half, theta + half


def mean_ci(values, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """The mean of ``values`` (one per seed; NaNs dropped) and its interval over seeds
    (:data:`CHOSEN` ``["mean"]``: Student's t); ``(mean, nan, nan)`` with fewer than two
    values or none spread: one run gives no spread to resample."""
    x = np.asarray(values, dtype=float)
    x = x[np.isfinite(x)]
    if x.size < 2:  # no value: no mean either; one: no spread
        return float(x[0]) if x.size else float("nan"), float("nan"), float("nan")
    lo, hi = t_intervals(x, "mean", confidence)
    return float(x.mean()), float(lo[0]), float(hi[0])


def stratified_t(
    strata: Sequence[tuple[np.ndarray, np.ndarray]], confidence: float = CONFIDENCE
) -> tuple[float, float, float]:
    """A mean over clusters (seeds) within strata (regimes), weighted by size: per stratum the
    clusters' values (a cluster's mean) and sizes (its days). The point is the pooled mean
    ``sum(size * value) / sum(size)``; its interval Student's t with the clusters' standard
    error within each stratum (the ratio estimator's) and Welch-Satterthwaite degrees of
    freedom. ``(point, nan, nan)`` when no stratum has two clusters."""
    total = sum(float(np.sum(n)) for _, n in strata)
    point = sum(float(np.sum(np.asarray(v) * np.asarray(n))) for v, n in strata) / total
    terms = []
    for v, n in strata:
        v, n = np.asarray(v, dtype=float), np.asarray(n, dtype=float)
        k = len(v)
        if k > 1:
            share = n.sum() / total
            m = (v * n).sum() / n.sum()
            w = n / n.sum()
            terms.append((share**2 * k / (k - 1) * np.sum(w**2 * (v - m) ** 2), k - 1))
    if not terms:
        return point, float("nan"), float("nan")
    se, df = _satterthwaite(terms, float(max(len(v) for v, _ in strata) - 1))
    half = float(_half_width(se, df, confidence))
    return point, point - half, point + half


def paired_ci(
    sums: Sequence[np.ndarray],
    sizes: Sequence[np.ndarray],
    reps: int = 10_000,
    rng: np.random.Generator | None = None,
    confidence: float = CONFIDENCE,
) -> tuple[float, float]:
    """The interval of a mean over days whose days come in seeds (clusters) within regimes
    (strata): per regime, each seed's sum over its days and its number of days. The estimate is
    ``sum(sums) / sum(sizes)``; its interval the one :data:`CHOSEN` ``["paired"]`` names, the t:
    :func:`stratified_t` of the seeds' means (no resamples: ``reps`` and ``rng``, kept for the
    callers, draw nothing)."""
    strata = [(np.asarray(s, dtype=float) / np.asarray(n, dtype=float), n) for s, n in zip(sums, sizes)]
    return stratified_t(strata, confidence)[1:]


def iqm_runs_ci(runs: Runs, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """The IQM of the runs pooled over regimes (rliable's aggregate IQM) and its interval
    (:data:`CHOSEN` ``["iqm"]``): the trimmed t with the standard error stratified by regime.
    ``(point, nan, nan)`` with one run per regime: nothing to resample."""
    runs = [np.asarray(r, dtype=float) for r in runs]
    pooled_runs = np.concatenate(runs)
    point = iqm(pooled_runs)
    if max(len(x) for x in runs) < 2:
        return point, float("nan"), float("nan")
    lo, hi = t_intervals(pooled_runs, "iqm", confidence, [len(x) for x in runs])
    return point, float(lo[0]), float(hi[0])


# --------------------------------------------------------------------------- the aggregates
# The aggregate table's median, mean and optimality gap, the performance profiles' bands and
# P(X > Y) (the report's Figure 5): intervals of the chosen method's kind (Student's t, the
# standard error taken within each regime), made without resamples, so no printed digit
# depends on a seed. Their coverage: AGGREGATE_COVERAGE (benchmarks/coverage.py).
def strata_t(
    x: np.ndarray, sizes: Sequence[int], by: str = "run", confidence: float = CONFIDENCE
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A weighted mean of each row of ``x`` ``(rows, n)``, whose values come in strata
    (regimes) of consecutive ``sizes``, with its t interval: ``by="run"`` weighs every value
    alike (the pooled mean), ``by="regime"`` every regime alike (the mean of the regimes'
    means). The standard error is taken within each regime (``sum_r W_r^2 s_r^2 / n_r``,
    ``W_r`` the regime's weight; a regime of one value adds none) and the degrees of freedom
    are Welch-Satterthwaite's. Rows whose regimes have no spread get the point as both ends.
    Returns ``(point, lo, hi)``, one value per row."""
    x = np.atleast_2d(np.asarray(x, dtype=float))
    sizes = list(sizes)
    weight = [k / sum(sizes) if by == "run" else 1 / len(sizes) for k in sizes]
    strata = list(zip(sizes, weight, np.split(x, np.cumsum(sizes), axis=1)))
    point = sum(w * part.mean(axis=1) for _, w, part in strata)
    terms = [(w**2 * part.var(axis=1, ddof=1) / k, k - 1) for k, w, part in strata if k > 1]
    se, df = _satterthwaite(terms, max(max(sizes) - 1, 1))
    half = _half_width(se, df, confidence)
    return point, point - half, point + half


@lru_cache(maxsize=64)
def _t_table(df: float) -> tuple[np.ndarray, np.ndarray]:
    """Student's t distribution function with ``df`` degrees of freedom, tabulated at 20,001
    of its quantiles (1e-9 .. 1 - 1e-9), for :func:`_t_cdf`."""
    from scipy.stats import t

    q = np.concatenate([[1e-9], np.linspace(1e-6, 1 - 1e-6, 19_999), [1 - 1e-9]])
    return t.ppf(q, df), q


def _t_cdf(z: np.ndarray, df: np.ndarray) -> np.ndarray:
    """Student's t distribution function, interpolated in :func:`_t_table` (within 1e-8 of
    scipy's; scipy's own takes microseconds a value, too slow for the median's search);
    ``df`` broadcasts along the last axis of ``z``."""
    df = np.broadcast_to(np.asarray(df, dtype=float), z.shape[-1:])
    out = np.empty(z.shape)
    for value in np.unique(df):
        cols = df == value
        zs, qs = _t_table(float(value))
        out[..., cols] = np.interp(z[..., cols], zs, qs, left=0.0, right=1.0)
    return out


def _regime_cdfs(means: np.ndarray, ses: np.ndarray, dfs: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """The t model of each regime's mean (``means``, ``ses`` ``(rows, R)``): ``cdf(v)`` with
    ``v`` ``(rows, ..., R)`` gives ``P(mean_r <= v_r)``; a regime of no spread is a point mass."""

    def cdf(v: np.ndarray) -> np.ndarray:
        shape = (means.shape[0],) + (1,) * (v.ndim - 2) + (means.shape[1],)
        m, s = means.reshape(shape), ses.reshape(shape)
        point = ~(s > 0)
        z = (v - m) / np.where(point, 1.0, s)
        return np.where(point, (v >= m).astype(float), _t_cdf(z, np.maximum(dfs, 1)))

    return cdf


def _count_probabilities(p: np.ndarray) -> np.ndarray:
    """The Poisson-binomial: ``p`` ``(..., R)`` independent probabilities -> ``(..., R + 1)``,
    the probability that exactly j of them happen."""
    out = np.zeros(p.shape[:-1] + (p.shape[-1] + 1,))
    out[..., 0] = 1.0
    for r in range(p.shape[-1]):
        pr = p[..., r : r + 1]
        out = out * (1 - pr) + np.concatenate([np.zeros_like(pr), out[..., :-1]], axis=-1) * pr
    return out


def median_cdf(means: np.ndarray, ses: np.ndarray, dfs: np.ndarray, grid: int) -> Callable[[np.ndarray], np.ndarray]:
    """``cdf(x)``: ``P(median of the regimes' means <= x)`` under the t model, per row (``x``
    ``(rows,)``, ``means``/``ses`` ``(rows, R)``): for odd R, at least (R + 1) / 2 of them at
    most x; for even R, the mean of the two middle ones, the lower one ``a`` taken at ``grid``
    quantiles of each regime's distribution in turn (the others' chances exact)."""
    from scipy.stats import t

    cdf = _regime_cdfs(means, ses, dfs)
    rows, R = means.shape
    if R % 2:
        return lambda x: _count_probabilities(cdf(x[:, None]))[:, (R + 1) // 2 :].sum(axis=1)
    k = R // 2
    q = (np.arange(grid) + 0.5) / grid
    point = ~(ses > 0)
    tq = t.ppf(q[None, :, None], np.maximum(dfs, 1)[None, None, :])
    a = np.where(point[:, None, :], means[:, None, :], means[:, None, :] + ses[:, None, :] * tq)  # (rows, grid, R)
    w = np.where(point[:, None, :], np.where(np.arange(grid) == 0, 1.0, 0.0)[None, :, None], 1.0 / grid)
    others = [[s for s in range(R) if s != r] for r in range(R)]
    # regime r's mean is the lower middle one, at a[..., r]: the others below it, and exactly k - 1
    below = [cdf(np.repeat(a[:, :, r : r + 1], R, axis=-1))[..., others[r]] for r in range(R)]
    exactly = [_count_probabilities(b)[..., k - 1] for b in below]

    def at(x: np.ndarray) -> np.ndarray:
        total = np.zeros(rows)
        for r in range(R):
            ar = a[:, :, r]
            upper = 2 * x[:, None] - ar  # the upper middle one at most this
            mid = np.clip(cdf(np.repeat(upper[..., None], R, axis=-1))[..., others[r]] - below[r], 0, None)
            none_mid = _count_probabilities(below[r] / np.clip(1 - mid, 1e-300, None))[..., k - 1]
            none_mid = none_mid * np.prod(1 - mid, axis=-1)
            total += np.sum(w[:, :, r] * np.where(upper >= ar, exactly[r] - none_mid, 0.0), axis=1)
        return np.clip(total, 0.0, 1.0)

    return at


def median_of_means_ci(runs: Runs, confidence: float = CONFIDENCE, grid: int = 400) -> tuple[float, float, float]:
    """The median of the regimes' mean scores (rliable's aggregate median) and its interval:
    each regime's mean modelled as Student's t about it (its standard error, ``n - 1`` degrees
    of freedom: the chosen interval of a mean), the median's distribution under that model
    computed (not drawn) and its 2.5 % and 97.5 % quantiles found by bisection. A regime of one
    run or of no spread is a point. ``(point, nan, nan)`` with one run per regime."""
    runs = [np.asarray(r, dtype=float) for r in runs]
    means = np.array([r.mean() for r in runs])
    point = float(np.median(means))
    if max(len(r) for r in runs) < 2:
        return point, float("nan"), float("nan")
    ses = np.array([sem(r) if len(r) > 1 else 0.0 for r in runs])
    ses = np.where(np.isfinite(ses), ses, 0.0)
    if not (ses > 0).any():  # no regime has spread: every model of the median is the point
        return point, point, point
    dfs = np.array([max(len(r) - 1, 1) for r in runs], dtype=float)
    lo, hi = median_intervals(means[None, :], ses[None, :], dfs, confidence, grid)
    return point, float(lo[0]), float(hi[0])


def median_intervals(
    means: np.ndarray,
    ses: np.ndarray,
    dfs: np.ndarray,
    confidence: float = CONFIDENCE,
    grid: int = 400,
    steps: int = 45,
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`median_of_means_ci`'s ends for each row of ``means``/``ses`` ``(rows, R)``
    (vectorised: the coverage simulation's datasets); ``dfs`` ``(R,)``; ``steps`` halvings of
    the search (45: each end to 3e-14 of its starting span, far below any printed digit)."""
    from scipy.stats import t

    alpha = (1 - confidence) / 2
    cdf = median_cdf(means, ses, dfs, grid)
    span = np.where(ses > 0, ses * t.ppf(1 - 1e-6, np.maximum(dfs, 1)), 0.0)
    out = []
    for target in (alpha, 1 - alpha):
        lo = (means - span).min(axis=1) - 1e-9
        hi = (means + span).max(axis=1) + 1e-9
        for _ in range(steps):
            mid = (lo + hi) / 2
            under = cdf(mid) < target
            lo, hi = np.where(under, mid, lo), np.where(under, hi, mid)
        out.append((lo + hi) / 2)
    return out[0], out[1]


def improvement_ci(x: Runs, y: Runs, confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """P(X > Y) averaged over regimes (per regime the share of (run of X, run of Y) pairs where
    X scores higher, ties half: the Mann-Whitney statistic) and its interval: per regime
    DeLong's variance of that share (the variances of each run's placement among the other
    side's runs, ``S_x / m + S_y / n``; a side of one run adds none), averaged over regimes,
    Student's t with Welch-Satterthwaite's degrees of freedom (``m + n - 2`` per regime),
    clipped to [0, 1]. ``(p, nan, nan)`` with one run per side and regime."""
    ps, terms, R = [], [], len(x)
    for a, b in zip(x, y):
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        psi = (a[:, None] > b[None, :]) + 0.5 * (a[:, None] == b[None, :])
        ps.append(psi.mean())
        vr = sum(v.var(ddof=1) / v.size for v in (psi.mean(axis=1), psi.mean(axis=0)) if v.size > 1) / R**2
        if a.size + b.size > 2:  # else one run a side: no spread
            terms.append((vr, a.size + b.size - 2))
    p = float(np.mean(ps))
    if max(max(len(a) for a in x), max(len(b) for b in y)) < 2:
        return p, float("nan"), float("nan")
    se, df = _satterthwaite(terms, 1.0)
    half = float(_half_width(se, df, confidence))
    return p, max(p - half, 0.0), min(p + half, 1.0)


def welch_t(
    points: Sequence[float],
    ses: Sequence[float],
    dfs: Sequence[float],
    weights: Sequence[float],
    confidence: float = CONFIDENCE,
) -> tuple[float, float, float]:
    """``sum_i w_i * point_i`` of independent estimates (each with its standard error and
    degrees of freedom) and its Student's t interval with Welch-Satterthwaite's degrees of
    freedom: the chosen t's kind for a contrast (a drop under delay, a difference of two IQMs).
    An estimate without a standard error (one run) adds none; ``(point, nan, nan)`` when none
    has one."""
    w, se, df = (np.asarray(v, dtype=float) for v in (weights, ses, dfs))
    point = float(np.dot(w, np.asarray(points, dtype=float)))
    keep = np.isfinite(se) & (df > 0)
    if not keep.any():
        return point, float("nan"), float("nan")
    se, dof = _satterthwaite(zip((w[keep] * se[keep]) ** 2, df[keep]), float(df[keep].min()))
    half = float(_half_width(se, dof, confidence))
    return point, point - half, point + half


def contrast_ci(runs: Runs, weights: Sequence[float], confidence: float = CONFIDENCE) -> tuple[float, float, float]:
    """``sum_r w_r * mean(runs_r)`` over independent regimes (one array of run scores each) and
    its interval (:func:`welch_t`, each regime's standard error of the mean, ``n_r - 1``
    degrees of freedom); a regime of one run adds no spread."""
    runs = [np.asarray(r, dtype=float) for r in runs]
    return welch_t([r.mean() for r in runs], [sem(r) for r in runs], [r.size - 1.0 for r in runs], weights, confidence)


def caption(statistic: str) -> str:
    """The interval's method and measured coverage, for a caption:
    ``"t interval; simulated coverage 95.0 % at 5 seeds, 94.6 % at 10"``."""
    label = "trimmed-t" if statistic == "iqm" else "t"  # CHOSEN: the t interval of each statistic
    return f"{label} interval; {_coverage(COVERAGE[statistic])}"


def aggregate_caption(statistic: str) -> str:
    """An aggregate's interval (:data:`AGGREGATE_METHODS`) and its measured coverage
    (:data:`AGGREGATE_COVERAGE`), for a caption: ``"t model of each regime's mean; simulated
    coverage 94.1 % at 5 seeds, 94.9 % at 10"``."""
    return f"{AGGREGATE_METHODS[statistic]}; {_coverage(AGGREGATE_COVERAGE[statistic])}"


def _coverage(cov: dict[int, float]) -> str:
    """A measured coverage at 5 and 10 seeds, as the captions quote it."""
    return f"simulated coverage {100 * cov[5]:.1f} % at 5 seeds, {100 * cov[10]:.1f} % at 10"
