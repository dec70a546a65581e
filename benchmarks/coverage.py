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

    python benchmarks/coverage.py [--datasets 2000] [--seed 0] [--markdown]
"""

from __future__ import annotations

import argparse
import re
import sys
import time
from pathlib import Path

import numpy as np
from scipy import stats as sps

from nutribench.stats import METHODS, design, intervals, iqm, stratified_design

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "reports" / "tuned_v2" / "results.md"


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


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datasets", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    start = time.perf_counter()
    rows = run(args.datasets, args.seed)
    sys.stdout.write(markdown(rows, args.datasets))
    sys.stdout.write(f"\n({time.perf_counter() - start:.0f} s)\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
