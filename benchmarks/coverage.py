"""Coverage of nominal 95 % intervals at 5 and 10 seeds: the simulation that chose each
statistic's interval in :mod:`nutribench.stats` (``CHOSEN``, ``COVERAGE``; docs/statistics.md,
"Intervals and their coverage"). Developer code, outside the shipped package.

Three statistics, as the tables print them:

* ``mean``: the mean over n seeds of one score per seed;
* ``iqm``: the IQM of the runs (one score per seed) of one regime, and of three regimes pooled
  (``iqm x3``: regime means 0, 1 and 2 within-regime standard deviations apart; resamples
  stratified by regime);
* ``paired``: the mean over n seeds of per-seed paired differences.

Each on normal scores and on skewed ones "like the ones measured here": the scores measured in
``reports/tuned_v2/results.md`` ("Per run": each v2 file's share of the gap per regime and
seed), standardised within each (file, regime), pooled and drawn from (``measured``), and a
gamma distribution of the same skewness (``gamma``); for ``paired`` the per-seed differences
v2 GRU-PPO - v2 PPO (G1's) and v2 - v1 per agent, standardised within regime. The target is
the population's mean or IQM (the IQM of a 2,000,000-draw sample). Four candidates: Student's
t (for the IQM Tukey-McLaughlin's trimmed t), percentile, BCa, bootstrap-t; a bootstrap over
one regime enumerates every resample (126 at n = 5, 92,378 at n = 10 are too many for 2,000
datasets: there 2,000 drawn), over three regimes 1,000 drawn.

The rule: per statistic, a method qualifies when its coverage is at least 92.5 % in every
cell (each distribution, both n); of those, the one with the narrowest mean width; when none
qualifies, the one whose lowest coverage is highest.

A second table (:func:`run_aggregates`) measures the intervals the module gives the other
aggregates of the report's Figure 5 (the median, the mean of regime means, the optimality gap,
the performance profile, P(X > Y): :data:`nutribench.stats.AGGREGATE_COVERAGE`), beside the
drawn percentile bootstrap the tables printed before; no method is chosen there.

    python benchmarks/coverage.py [--datasets 2000] [--seed 0] [--no-aggregates]
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy import stats as sps

from nutribench.stats import (
    CONFIDENCE,
    Design,
    design,
    improvement_ci,
    iqm,
    mean_se,
    median_cdf,
    median_intervals,
    strata_t,
    stratified_indices,
    t_intervals,
    trimmed_se,
    weighted_quantiles,
)

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "reports" / "tuned_v2" / "results.md"

#: The candidate intervals the simulation weighs (the package keeps the t, :func:`nutribench.stats.t_intervals`).
METHODS: tuple[str, ...] = ("percentile", "bca", "bootstrap-t", "t")


def stratified_design(
    sizes: Sequence[int], reps: int = 2000, rng: np.random.Generator | None = None, exact: bool | None = None
) -> Design:
    """The resamples of runs in strata of ``sizes`` laid side by side (one stratum's runs after
    the other's): within each stratum its runs redrawn with replacement. One stratum: :func:`design`."""
    if len(sizes) == 1:
        return design(sizes[0], reps, rng, exact)
    rng = rng if rng is not None else np.random.default_rng(0)
    offsets = np.cumsum([0, *sizes[:-1]])
    idx = np.concatenate([i + o for i, o in zip(stratified_indices(sizes, reps, rng), offsets)], axis=1)
    return Design(idx, np.full(reps, 1.0 / reps), False)


def intervals(
    x: np.ndarray,
    statistic: str,
    method: str,
    d: Design | None = None,
    confidence: float = CONFIDENCE,
    sizes: Sequence[int] | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The ``method`` interval (:data:`METHODS`) of ``statistic`` (``"mean"``, ``"iqm"``) of
    each row of ``x`` ``(rows, n)``, vectorised over rows (the simulation's datasets): ``(lo,
    hi)``. ``"t"`` is the package's (:func:`nutribench.stats.t_intervals`); ``"percentile"``,
    ``"bca"`` (Efron's bias-corrected and accelerated, acceleration from the jackknife) and
    ``"bootstrap-t"`` (resamples studentized by the same standard error) draw on ``d``, the
    bootstrap's resamples (default :func:`stratified_design` of ``sizes``). ``sizes``: strata
    (regimes) of consecutive lengths along a row, for the IQM's standard error."""
    from scipy.stats import norm

    if method == "t":
        return t_intervals(x, statistic, confidence, sizes)
    x = np.atleast_2d(np.asarray(x, dtype=float))
    n = x.shape[1]
    sizes = [n] if sizes is None else list(sizes)

    def stat(v):
        return iqm(v, axis=-1) if statistic == "iqm" else v.mean(axis=-1)

    def se_of(v):
        return trimmed_se(v, sizes) if statistic == "iqm" else mean_se(v)

    alpha = (1 - confidence) / 2
    theta = stat(x)
    se, _ = se_of(x)
    d = d or stratified_design(sizes)
    boot = stat(x[:, d.idx])  # (rows, resamples)
    w = d.weights
    if method == "percentile":
        q = np.tile([alpha, 1 - alpha], (len(x), 1))
        out = weighted_quantiles(boot, w, q)
        return out[:, 0], out[:, 1]
    if method == "bca":
        below = ((boot < theta[:, None]) * w).sum(1) + 0.5 * ((boot == theta[:, None]) * w).sum(1)
        z0 = norm.ppf(np.clip(below / w.sum(), 1e-6, 1 - 1e-6))
        jack = np.stack([stat(np.delete(x, i, axis=1)) for i in range(n)], axis=1)
        dev = jack.mean(axis=1, keepdims=True) - jack
        den = 6 * (dev**2).sum(1) ** 1.5
        a = np.divide((dev**3).sum(1), den, out=np.zeros(len(x)), where=den > 0)
        z = norm.ppf([alpha, 1 - alpha])[None, :]
        q = norm.cdf(z0[:, None] + (z0[:, None] + z) / (1 - a[:, None] * (z0[:, None] + z)))
        out = weighted_quantiles(boot, w, q)
        return out[:, 0], out[:, 1]
    if method == "bootstrap-t":
        se_b, _ = se_of(x[:, d.idx])
        with np.errstate(divide="ignore", invalid="ignore"):
            tt = (boot - theta[:, None]) / se_b
        keep = np.isfinite(tt)  # a resample of one value repeated has no spread: left out
        tt = np.where(keep, tt, 0.0)
        ww = np.where(keep, w[None, :], 0.0)
        out = np.stack(
            [weighted_quantiles(tt[i : i + 1], ww[i], np.array([[alpha, 1 - alpha]]))[0] for i in range(len(x))]
        )
        return theta - out[:, 1] * se, theta - out[:, 0] * se
    raise ValueError(f"method {method!r}: one of {', '.join(METHODS)}")


def measured_runs(path: Path = RESULTS) -> dict[str, dict[str, np.ndarray]]:
    """file -> regime -> the per-seed shares (%) of results.md's "Per run" tables."""
    out: dict[str, dict[str, np.ndarray]] = {}
    name = None
    for line in path.read_text().splitlines():
        m = re.match(r"\*\*(\w+)\*\*:", line)
        if m:
            name = m.group(1)
            out[name] = {}
        elif name and re.match(r"\| run\d \|", line):
            cells = [c.strip() for c in line.strip("|").split("|")]
            out[name][cells[0]] = np.array([float(c.split()[0]) for c in cells[1:] if c])
    return out


def standardised(groups: list[np.ndarray]) -> np.ndarray:
    """Each group's values less its mean (scaled by sqrt(n / (n - 1)) for the mean taken out),
    pooled and divided by the pool's standard deviation: a group's outlying seed keeps its
    tail (dividing each group by its own deviation would cap a 5-value group's skewness)."""
    parts = [(g - g.mean()) * np.sqrt(len(g) / (len(g) - 1)) for g in groups if len(g) > 2]
    pool = np.concatenate(parts)
    return pool / pool.std()


def pools() -> dict[str, np.ndarray]:
    """The measured residuals: run scores, and paired per-seed differences."""
    runs = measured_runs()
    scores = standardised([v for f in runs.values() for r, v in f.items() if r != "run0"])
    v2 = {k.removesuffix("_tuned_v2"): f for k, f in runs.items()}
    diffs = [v2["gru_ppo"][r] - v2["ppo"][r] for r in v2["ppo"] if r != "run0"]
    return {"scores": scores, "differences": standardised(diffs)}


class Population:
    """A distribution to draw datasets from, and its mean and IQM."""

    def __init__(self, name: str, draw, rng: np.random.Generator):
        self.name, self.draw = name, draw
        big = draw(rng, (2_000_000,))
        self.mean, self.iqm = float(big.mean()), float(iqm(big))


def populations(pool: np.ndarray, rng: np.random.Generator) -> list[Population]:
    skew = float(sps.skew(pool))
    k = 4 / skew**2
    sign = np.sign(skew)
    return [
        Population("normal", lambda r, s: r.standard_normal(s), rng),
        Population(f"gamma (skewness {skew:+.2f})", lambda r, s: sign * (r.gamma(k, 1.0, s) - k) / np.sqrt(k), rng),
        Population(f"measured ({len(pool)} residuals)", lambda r, s: r.choice(pool, size=s), rng),
    ]


def coverage(pop: Population, statistic: str, n: int, strata: int, datasets: int, rng) -> dict[str, tuple]:
    """Per method: (coverage, mean width) over ``datasets`` simulated datasets."""
    offsets = np.repeat(np.arange(strata, dtype=float), n)
    if strata == 1:
        target = pop.mean if statistic == "mean" else pop.iqm
    else:  # the IQM of the mixture of the strata
        big = pop.draw(rng, (strata, 700_000)) + np.arange(strata)[:, None]
        target = float(iqm(big))
    x = pop.draw(rng, (datasets, n * strata)) + offsets
    if strata == 1:
        d = design(n, 2000, rng, exact=n <= 5)
    else:
        d = stratified_design([n] * strata, 1000, rng)
    out = {}
    for method in METHODS:
        los, his = [], []
        for chunk in np.array_split(x, max(1, datasets // 250)):
            lo, hi = intervals(chunk, statistic, method, d, sizes=[n] * strata)
            los.append(lo)
            his.append(hi)
        lo, hi = np.concatenate(los), np.concatenate(his)
        out[method] = (float(np.mean((lo <= target) & (target <= hi))), float(np.mean(hi - lo)))
    return out


def run(datasets: int = 2000, seed: int = 0) -> list[dict]:
    rng = np.random.default_rng(seed)
    p = pools()
    rows = []
    cases = [("mean", "mean", 1, "scores"), ("iqm", "iqm", 1, "scores"), ("iqm x3", "iqm", 3, "scores")]
    cases.append(("paired", "mean", 1, "differences"))
    for label, statistic, strata, pool in cases:
        for pop in populations(p[pool], rng):
            for n in (5, 10):
                cov = coverage(pop, statistic, n, strata, datasets, rng)
                rows.append({"statistic": label, "scores": pop.name, "n": n, **cov})
    return rows


#: A method qualifies when its coverage is at least this in every cell.
QUALIFIES = 0.925


def choose(rows: list[dict]) -> dict[str, tuple[str, dict[int, float], bool]]:
    """Per statistic, the narrowest (mean width) of the methods covering at least
    :data:`QUALIFIES` in every cell, else the one whose lowest coverage is highest; and the
    chosen one's lowest coverage at each n; and whether it qualified."""
    out = {}
    for label in dict.fromkeys(r["statistic"] for r in rows):
        mine = [r for r in rows if r["statistic"] == label]
        worst = {m: min(r[m][0] for r in mine) for m in METHODS}
        width = {m: np.mean([r[m][1] for r in mine]) for m in METHODS}
        ok = [m for m in METHODS if worst[m] >= QUALIFIES]
        best = min(ok, key=width.get) if ok else max(METHODS, key=worst.get)
        out[label] = (best, {n: min(r[best][0] for r in mine if r["n"] == n) for n in (5, 10)}, bool(ok))
    return out


def markdown(rows: list[dict], datasets: int) -> str:
    lines = [
        f"Coverage of nominal 95 % intervals ({datasets} simulated datasets per cell; mean width in within-regime "
        "standard deviations in brackets)",
        "",
        "| statistic | scores | n | " + " | ".join(METHODS) + " |",
        "|---|---|---|" + "---|" * len(METHODS),
    ]
    for r in rows:
        cells = [f"{100 * r[m][0]:.1f} % ({r[m][1]:.2f})" for m in METHODS]
        lines.append(f"| {r['statistic']} | {r['scores']} | {r['n']} | " + " | ".join(cells) + " |")
    lines += [
        "",
        f"Chosen (the narrowest covering {100 * QUALIFIES:.1f} % everywhere, else the highest lowest coverage):",
        "",
    ]
    for label, (method, cov) in choose(rows).items():
        lines.append(
            f"- {label}: {method} (lowest coverage {100 * cov[5]:.1f} % at n = 5, {100 * cov[10]:.1f} % at n = 10)"
        )
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------- the aggregates
#: The aggregates of the report's Figure 5 that the first simulation does not cover, as the
#: aggregate table computes them over R regimes of n seeds (regime means 0.5 within-regime
#: standard deviations apart): label -> (regimes, statistic).
AGGREGATE_CASES: dict[str, tuple[int, str]] = {
    "median x7": (7, "median"),
    "median x6": (6, "median"),
    "mean x7": (7, "mean"),
    "optimality gap x7": (7, "gap"),
    "profile x7 (fraction ~0.5)": (7, "profile50"),
    "profile x7 (fraction ~0.9)": (7, "profile90"),
    "P(X > Y) x7": (7, "improvement"),
}
#: P(X > Y)'s shift: X's runs score this many within-regime standard deviations above Y's.
SHIFT = 0.5


def _aggregate_setup(pop: Population, R: int, statistic: str, rng) -> tuple[float, dict]:
    """The population value of ``statistic`` over ``R`` regimes (regime r's scores ``pop + r/2``)
    and its parameters (the cap, the threshold)."""
    offsets = 0.5 * np.arange(R)
    big = pop.draw(rng, (R, 400_000)) + offsets[:, None]
    centre = float(offsets.mean())
    if statistic == "median":
        return float(np.median(pop.mean + offsets)), {}
    if statistic == "mean":
        return float(pop.mean + centre), {}
    if statistic == "gap":
        cap = centre + 0.5  # the cap bites: most regimes score below it, the upper ones above
        return float(cap - np.minimum(big, cap).mean()), {"cap": cap}
    if statistic.startswith("profile"):
        share = 0.5 if statistic == "profile50" else 0.9
        tau = float(np.quantile(big, 1 - share))
        return float((big > tau).mean()), {"tau": tau}
    if statistic == "improvement":
        a, b = pop.draw(rng, (2_000_000,)) + SHIFT, pop.draw(rng, (2_000_000,))
        return float(np.mean(a > b) + 0.5 * np.mean(a == b)), {}
    raise ValueError(statistic)


def _aggregate_values(x: np.ndarray, R: int, n: int, statistic: str, par: dict) -> np.ndarray:
    """``statistic`` of each dataset (and resample): ``x`` ``(..., R * n)``, regimes consecutive."""
    regimes = x.reshape(*x.shape[:-1], R, n)
    if statistic == "median":
        return np.median(regimes.mean(axis=-1), axis=-1)
    if statistic == "mean":
        return regimes.mean(axis=-1).mean(axis=-1)
    if statistic == "gap":
        return par["cap"] - np.minimum(x, par["cap"]).mean(axis=-1)
    return (x > par["tau"]).mean(axis=-1)


def _aggregate_chosen(x: np.ndarray, y: np.ndarray | None, R: int, n: int, statistic: str, par: dict):
    """The module's interval (the tables') of each dataset: ``(lo, hi)``."""
    sizes = [n] * R
    if statistic == "mean":
        return strata_t(x, sizes, "regime")[1:]
    if statistic == "gap":
        _, lo, hi = strata_t(np.minimum(x, par["cap"]), sizes, "run")
        return par["cap"] - hi, par["cap"] - lo
    if statistic.startswith("profile"):
        _, lo, hi = strata_t((x > par["tau"]).astype(float), sizes, "run")
        return np.clip(lo, 0, 1), np.clip(hi, 0, 1)
    ends = [improvement_ci(list(a.reshape(R, n)), list(b.reshape(R, n)))[1:] for a, b in zip(x, y)]
    return np.array([e[0] for e in ends]), np.array([e[1] for e in ends])


#: The median's ends are searched for (45 halvings each) on this many datasets, for the width.
MEDIAN_WIDTHS = 25


def _median_coverage(x: np.ndarray, R: int, n: int, target: float) -> tuple[float, float]:
    """The median interval's coverage and mean width: an interval holds the target exactly
    when the median's distribution function there lies in [2.5 %, 97.5 %] (one evaluation per
    dataset, not the two searches for its ends); the width from the ends of the first
    :data:`MEDIAN_WIDTHS` datasets (:func:`nutribench.stats.median_intervals`)."""
    regimes = x.reshape(len(x), R, n)
    means, ses, dfs = regimes.mean(axis=-1), regimes.std(axis=-1, ddof=1) / np.sqrt(n), np.full(R, n - 1.0)
    g = np.concatenate(
        [
            median_cdf(means[i : i + 250], ses[i : i + 250], dfs, 400)(np.full(len(means[i : i + 250]), target))
            for i in range(0, len(x), 250)
        ]
    )
    lo, hi = median_intervals(means[:MEDIAN_WIDTHS], ses[:MEDIAN_WIDTHS], dfs)
    return float(np.mean((g >= 0.025) & (g <= 0.975))), float(np.mean(hi - lo))


def _aggregate_percentile(x, y, R: int, n: int, statistic: str, par: dict, rng, reps: int = 1000):
    """The percentile interval of ``reps`` stratified resamples (what the tables printed before)."""
    d = stratified_design([n] * R, reps, rng)
    q = np.array([[0.025, 0.975]])
    if statistic != "improvement":
        boot = _aggregate_values(x[:, d.idx], R, n, statistic, par)
    else:
        e = stratified_design([n] * R, reps, rng)
        a = x[:, d.idx].reshape(len(x), reps, R, n)
        b = y[:, e.idx].reshape(len(y), reps, R, n)
        boot = np.mean((a[..., :, None] > b[..., None, :]) + 0.5 * (a[..., :, None] == b[..., None, :]), axis=(-1, -2))
        boot = boot.mean(axis=-1)
    out = weighted_quantiles(boot, d.weights, np.tile(q, (len(x), 1)))
    return out[:, 0], out[:, 1]


def run_aggregates(datasets: int = 2000, seed: int = 0) -> list[dict]:
    """Coverage of the aggregates' intervals (:data:`AGGREGATE_CASES`) on the three kinds of
    scores: the module's method (``t``) and, for reference, the drawn percentile bootstrap."""
    rng = np.random.default_rng([seed, 1])
    pool = pools()["scores"]
    rows = []
    for label, (R, statistic) in AGGREGATE_CASES.items():
        for pop in populations(pool, rng):
            target, par = _aggregate_setup(pop, R, statistic, rng)
            for n in (5, 10):
                offsets = np.repeat(0.5 * np.arange(R), n)
                x = pop.draw(rng, (datasets, R * n)) + offsets
                y = pop.draw(rng, (datasets, R * n)) + offsets - SHIFT if statistic == "improvement" else None
                cells = {}
                for method in ("percentile", "t"):
                    if method == "t" and statistic == "median":
                        cells[method] = _median_coverage(x, R, n, target)
                        continue
                    los, his = [], []
                    for i in range(0, datasets, 250):
                        xi, yi = x[i : i + 250], None if y is None else y[i : i + 250]
                        if method == "t":
                            lo, hi = _aggregate_chosen(xi, yi, R, n, statistic, par)
                        else:
                            lo, hi = _aggregate_percentile(xi, yi, R, n, statistic, par, rng)
                        los.append(lo)
                        his.append(hi)
                    lo, hi = np.concatenate(los), np.concatenate(his)
                    cells[method] = (float(np.mean((lo <= target) & (target <= hi))), float(np.mean(hi - lo)))
                rows.append({"statistic": label, "scores": pop.name, "n": n, **cells})
    return rows


def aggregate_coverage(rows: list[dict]) -> dict[str, dict[int, float]]:
    """Per statistic of the aggregates (the caption's name: median, mean, gap, profile,
    improvement), the module's lowest coverage at each n over its cells."""
    out: dict[str, dict[int, float]] = {}
    for r in rows:
        name = AGGREGATE_CASES[r["statistic"]][1]
        name = "profile" if name.startswith("profile") else name
        cov = out.setdefault(name, {5: 1.0, 10: 1.0})
        cov[r["n"]] = min(cov[r["n"]], r["t"][0])
    return out


def aggregate_markdown(rows: list[dict], datasets: int) -> str:
    lines = [
        f"Coverage of the aggregates' nominal 95 % intervals ({datasets} simulated datasets per cell; mean width in "
        "brackets; t: the module's interval, percentile: 1,000 drawn stratified resamples, as before)",
        "",
        "| statistic | scores | n | percentile | t |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        cells = [f"{100 * r[m][0]:.1f} % ({r[m][1]:.2f})" for m in ("percentile", "t")]
        lines.append(f"| {r['statistic']} | {r['scores']} | {r['n']} | " + " | ".join(cells) + " |")
    lines += ["", "Lowest coverage of the module's interval:", ""]
    for name, cov in aggregate_coverage(rows).items():
        lines.append(f"- {name}: {100 * cov[5]:.1f} % at n = 5, {100 * cov[10]:.1f} % at n = 10")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-aggregates", action="store_true", help="the first table only (mean, IQM, paired)")
    args = ap.parse_args(argv)
    start = time.perf_counter()
    rows = run(args.datasets, args.seed)
    sys.stdout.write(markdown(rows, args.datasets))
    if not args.no_aggregates:
        sys.stdout.write("\n" + aggregate_markdown(run_aggregates(args.datasets, args.seed), args.datasets))
    sys.stdout.write(f"\n({time.perf_counter() - start:.0f} s)\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
