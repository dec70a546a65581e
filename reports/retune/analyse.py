"""The re-tuning study's pre-registered readings (README.md, "Metric and readings" and addendum
1), from a database of its held-out jobs (the grid's, or one the archives in ``data/`` were
imported into), as Markdown:

* R1: per agent (PPO, GRU-PPO) and held-out regime, each of its three files' IQM over the seeds
  of the run scores (the share of the never -> planner gap, ``run_scores``) with the trimmed-t
  interval (``nutribench.stats.iqm_runs_ci``), the spread (max - min of the three IQMs) and the
  published file's (study A's) rank among the three;
* R2: GRU-PPO file i minus PPO file j, the 9 pairs: the mean over seeds of the paired
  difference (same seed, same regime) with the t interval (``nutribench.stats.mean_ci``), per
  regime and pooled (per seed the mean over the three regimes, then over seeds);
* R3: the mean over the 9 pairs of the per-seed difference, with the percentile interval of
  the bootstrap that resamples GRU-PPO's studies, PPO's studies and the seeds together (each
  level with replacement), every resample enumerated and weighed by its probability
  (addendum 1), per regime and pooled;
* R4: MC's and DDQN's v2 files, per regime IQM and interval as R1;
* E1-E3, each "holds", "fails" or "not yet run".

A cell with no job in the database says "not yet run"; a cell with some of the 10 seeds is
computed on those and says how many. The spread, the rank, R3 and the expectations need every
cell they name complete (all 10 seeds), else they say "not yet run": nothing is read from a
partial grid.

    python reports/retune/analyse.py DB [--out reports/retune/results.md]

DB: a database the archives in ``data/`` were imported into (``nutribench db import``), or a
copy of the grid's ``grid.db``: the grid writes it from its frozen checkout, whose schema may
be older than this checkout's (then the script says so in one line); upgrade the copy
(``nutribench run --upgrade-only --db COPY``), never the grid's own database while it runs.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pandas as pd

from nutribench.stats import caption, design, iqm_runs_ci, mean_ci, percentile_interval

HERE = Path(__file__).resolve().parent
# the house's Markdown table and percent cell, as reports/tuned_v2/analyse.py takes them
_spec = importlib.util.spec_from_file_location("tuned_v1_analyse", HERE.parents[1] / "reports" / "tuned" / "analyse.py")
v1 = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(v1)
md_table, pct = v1.md_table, v1.pct
REGIMES = ("run1", "run3", "run6")
SEEDS = tuple(range(5000, 5010))
STUDIES = ("A", "B", "C")
#: each agent's three files, studies A (the published v2 file), B and C
FILES = {
    "PPO": ("ppo_tuned_v2", "ppo_tuned_v2b", "ppo_tuned_v2c"),
    "GRU-PPO": ("gru_ppo_tuned_v2", "gru_ppo_tuned_v2b", "gru_ppo_tuned_v2c"),
}
OTHERS = ("mc_tuned_v2", "ddqn_tuned_v2")  # R4
E1_POINTS = 0.15  # E1: a spread over 15 points of the gap
NOT_RUN = "not yet run"


# --------------------------------------------------------------------------- the cells
def cells(scores: pd.DataFrame) -> dict[tuple[str, str], pd.Series]:
    """Per (file, regime) the finite run scores, indexed by seed (sorted)."""
    s = scores[np.isfinite(scores["score"].to_numpy(dtype=float))]
    return {
        (str(a), str(r)): g.set_index("seed")["score"].astype(float).sort_index()
        for (a, r), g in s.groupby(["algo", "regime"])
    }


def complete(c: pd.Series | None) -> bool:
    return c is not None and set(SEEDS) <= set(c.index)


def seeds_note(n: int) -> str:
    return "" if n >= len(SEEDS) else f" ({n} of {len(SEEDS)} seeds)"


def interval_text(point: float, lo: float, hi: float, signed: bool = False) -> str:
    """``55 [47, 63]`` (a level) or ``+30 [+13, +47]`` (a difference), in % of the gap."""
    if not np.isfinite(lo):
        return f"{pct(point, signed)} [single seed]"
    return f"{pct(point, signed)} [{pct(lo, signed)}, {pct(hi, signed)}]"


# --------------------------------------------------------------------------- R1, R4
def level(c: pd.Series | None) -> tuple[float, float, float] | None:
    """The IQM over a cell's seeds and its interval (the trimmed t), None for no run."""
    return None if c is None else iqm_runs_ci([c.to_numpy()])


def level_text(c: pd.Series | None) -> str:
    if c is None:
        return NOT_RUN
    return interval_text(*level(c)) + seeds_note(len(c))


def spread_and_rank(cs: dict, files: Sequence[str], regime: str) -> tuple[float, int] | None:
    """R1: the spread (max - min) of the files' IQMs on ``regime`` and the first file's rank
    among them (1: the highest; a tie with a higher IQM counts as first too), None unless
    every file's cell is complete."""
    if not all(complete(cs.get((f, regime))) for f in files):
        return None
    points = [level(cs[f, regime].loc[list(SEEDS)])[0] for f in files]
    return max(points) - min(points), 1 + sum(p > points[0] for p in points[1:])


def r1(cs: dict) -> tuple[list[str], dict]:
    lines = ["## R1: each agent's three files", ""]
    found = {}
    for agent, files in FILES.items():
        rows = []
        for r in REGIMES:
            sr = spread_and_rank(cs, files, r)
            found[agent, r] = sr
            tail = [NOT_RUN, NOT_RUN] if sr is None else [pct(sr[0]), f"{sr[1]} of {len(files)}"]
            rows.append([r, *(level_text(cs.get((f, r))) for f in files), *tail])
        head = ["regime", *(f"{s} `{f}`" for s, f in zip(STUDIES, files)), "spread (max - min)", "A's rank"]
        lines += [f"**{agent}**: IQM over seeds [95 % {caption('iqm')}]", "", *md_table(head, rows), ""]
    return lines, found


def r4(cs: dict) -> list[str]:
    rows = [[f"`{f}`", *(level_text(cs.get((f, r))) for r in REGIMES)] for f in OTHERS]
    return [
        "## R4: the other agents' v2 files",
        "",
        f"IQM over seeds [95 % {caption('iqm')}]; one tuning draw each, no spread measured.",
        "",
        *md_table(["file", *REGIMES], rows),
        "",
    ]


# --------------------------------------------------------------------------- R2
def paired(cs: dict, a: str, b: str, regimes: Sequence[str]) -> pd.Series | None:
    """Per seed, ``a``'s score minus ``b``'s on the same seed, averaged over ``regimes``, on the
    seeds both files have on every one of them; None where a regime lacks either file."""
    parts = [(cs.get((a, r)), cs.get((b, r))) for r in regimes]
    if any(x is None or y is None for x, y in parts):
        return None
    d = pd.concat([x - y for x, y in parts], axis=1).dropna()  # x - y aligns on the seed
    return d.mean(axis=1) if len(d) else None


def paired_text(d: pd.Series | None) -> str:
    return NOT_RUN if d is None else interval_text(*mean_ci(d.to_numpy()), signed=True) + seeds_note(len(d))


def r2(cs: dict) -> list[str]:
    rows = []
    for gs, g in zip(STUDIES, FILES["GRU-PPO"]):
        for ps, p in zip(STUDIES, FILES["PPO"]):
            per = [paired_text(paired(cs, g, p, (r,))) for r in REGIMES]
            rows.append([f"GRU-PPO {gs} - PPO {ps}", *per, paired_text(paired(cs, g, p, REGIMES))])
    return [
        "## R2: G1 per pair of studies (GRU-PPO file - PPO file)",
        "",
        f"Mean paired difference by seed, points of the gap [95 % {caption('paired')}]; pooled: per seed "
        "the mean over the three held-out regimes, then the mean over seeds.",
        "",
        *md_table(["pair", *REGIMES, "pooled"], rows),
        "",
    ]


# --------------------------------------------------------------------------- R3
def count_fractions(k: int) -> tuple[np.ndarray, np.ndarray]:
    """Every bootstrap resample of ``k`` values as the fraction of draws each value gets
    ``(resamples, k)``, and each resample's probability (``nutribench.stats.design``)."""
    d = design(k, exact=True)
    counts = (d.idx[:, :, None] == np.arange(k)).sum(axis=1)
    return counts / k, d.weights


def r3_interval(g: np.ndarray, p: np.ndarray, confidence: float = 0.95) -> tuple[float, float, float, int]:
    """R3 on scores ``g`` ``(seeds, GRU-PPO studies)`` and ``p`` ``(seeds, PPO studies)``: the
    mean over every (GRU-PPO study, PPO study) pair of the mean over seeds of the paired
    difference, and the percentile interval of the bootstrap resampling the GRU-PPO studies,
    the PPO studies and the seeds, each with replacement and independently. The statistic is
    linear in each level's count fractions (``w . (g u - p v)``), so every resample is
    enumerated (multisets, weighed by the product of their multinomial probabilities), none
    drawn. Returns (point, lo, hi, distinct resamples)."""
    g, p = np.asarray(g, dtype=float), np.asarray(p, dtype=float)
    w, pw = count_fractions(len(g))
    u, pu = count_fractions(g.shape[1])
    v, pv = count_fractions(p.shape[1])
    diff = ((g @ u.T)[:, :, None] - (p @ v.T)[:, None, :]).reshape(len(g), -1)  # (seeds, u x v)
    values = w @ diff  # (seed resamples, study resamples): a few hundred MB at most for 10 seeds
    weights = pw[:, None] * np.outer(pu, pv).ravel()[None, :]
    point = float(g.mean() - p.mean())
    lo, hi = percentile_interval(values.ravel(), confidence, weights.ravel())
    return point, lo, hi, values.size


def r3_matrices(cs: dict, regimes: Sequence[str]) -> tuple[np.ndarray, np.ndarray] | None:
    """(GRU-PPO, PPO) scores ``(seeds, 3)`` on ``regimes`` (several: per seed their mean),
    None unless all six files are complete on every one of them."""
    names = [*FILES["GRU-PPO"], *FILES["PPO"]]
    if not all(complete(cs.get((f, r))) for f in names for r in regimes):
        return None
    m = np.array([[cs[f, r].loc[list(SEEDS)].to_numpy() for r in regimes] for f in names]).mean(axis=1).T
    return m[:, :3], m[:, 3:]


def r3(cs: dict) -> tuple[list[str], tuple | None]:
    rows, pooled = [], None
    for label, regs in [*((r, (r,)) for r in REGIMES), ("pooled", REGIMES)]:
        m = r3_matrices(cs, regs)
        if m is None:
            rows.append([label, NOT_RUN, ""])
            continue
        point, lo, hi, n = r3_interval(*m)
        pooled = (point, lo, hi) if label == "pooled" else pooled
        rows.append([label, interval_text(point, lo, hi, signed=True), f"{n:,}"])
    return [
        "## R3: G1 over studies and seeds",
        "",
        "The mean over the 9 (GRU-PPO file, PPO file) pairs of the per-seed difference, points of the gap "
        "[95 % percentile interval of the bootstrap resampling GRU-PPO's 3 studies, PPO's 3 studies and the "
        "10 seeds together, each level with replacement: every resample enumerated and weighed by its "
        "multinomial probability (10 x 10 x 92,378), none drawn]; pooled: per seed the mean over the three "
        "held-out regimes. Needs all six files on all 10 seeds.",
        "",
        *md_table(["regimes", "mean over the 9 pairs", "resamples"], rows),
        "",
    ], pooled


# --------------------------------------------------------------------------- E1-E3
def expectations(found: dict, pooled: tuple | None) -> list[str]:
    """E1-E3 (README.md, "Expectations"), each read only once every cell it names is complete."""
    rows = []
    spreads = {k: v[0] for k, v in found.items() if v is not None}
    if len(spreads) < len(found):
        rows.append(["E1", NOT_RUN, f"needs R1's spreads on every agent and regime ({len(spreads)} of {len(found)})"])
    else:
        (agent, regime), top = max(spreads.items(), key=lambda kv: kv[1])
        holds = top > E1_POINTS
        rows.append(["E1", "holds" if holds else "fails", f"largest spread {100 * top:.1f} points ({agent}, {regime})"])
    if pooled is None:
        rows.append(["E2", NOT_RUN, "needs R3 pooled (all six files on all three regimes)"])
    else:
        text = interval_text(*pooled, signed=True)
        rows.append(["E2", "holds" if pooled[1] > 0 else "fails", f"R3 pooled {text}"])
    ranks = {k: v[1] for k, v in found.items() if v is not None}
    if len(ranks) < len(found):
        rows.append(["E3", NOT_RUN, f"needs A's rank on every agent and regime ({len(ranks)} of {len(found)})"])
    else:
        first = sum(r == 1 for r in ranks.values())
        rows.append(["E3", "fails" if first == len(ranks) else "holds", f"A first on {first} of {len(ranks)}"])
    return [
        "## Expectations",
        "",
        "E1: some spread over 15 points; E2: R3's pooled interval above 0; E3: A not first on all three "
        "regimes for both agents.",
        "",
        *md_table(["", "reading", "on"], rows),
        "",
    ]


# --------------------------------------------------------------------------- the page
def markdown(scores: pd.DataFrame) -> str:
    """The readings from the run scores (columns regime, algo, seed, score; any subset of the grid)."""
    cs = cells(scores)
    held = {a for a, _ in cs}
    names = [*FILES["PPO"], *FILES["GRU-PPO"], *OTHERS]
    lines = [
        "# Re-tuning: the held-out readings (R1-R4, E1-E3)",
        "",
        "Written by `python reports/retune/analyse.py DB`; shares of the never -> planner gap in %, per job "
        'the mean over its test days (`run_scores`). A cell with no job is "not yet run"; one with fewer '
        "than 10 seeds says how many; spreads, ranks, R3 and E1-E3 wait for every cell they name.",
        "",
        f"Files present: {', '.join(f'`{n}`' for n in names if n in held) or 'none'}; "
        f"not yet run: {', '.join(f'`{n}`' for n in names if n not in held) or 'none'}.",
        "",
    ]
    part, found = r1(cs)
    lines += part + r2(cs)
    part, pooled = r3(cs)
    lines += part + r4(cs) + expectations(found, pooled)
    return "\n".join(lines)


def read_scores(db: str) -> pd.DataFrame:
    """The run scores of ``db`` (``jobs.py``'s ``job_rows``); none for a database of no eval days."""
    from nutribench.store import read_episode_metrics

    if read_episode_metrics(db, phase="eval").empty:
        return pd.DataFrame(columns=["regime", "algo", "seed", "score"])
    spec = importlib.util.spec_from_file_location("retune_jobs", HERE / "jobs.py")
    jobs = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(jobs)
    return jobs.job_rows(db)[0]


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("db", help="the grid's database, or one the archives in data/ were imported into")
    ap.add_argument("--out", default=None, help="write the Markdown here (default: print it)")
    a = ap.parse_args(argv)
    from nutribench.errors import UserError

    if not Path(a.db).is_file():
        print(f"error: no database at {a.db}", file=sys.stderr)
        return 2
    try:
        scores = read_scores(a.db)
    except UserError as e:  # an old schema (the grid's frozen checkout), not a database: one line
        print(f"error: {e}", file=sys.stderr)
        return 2
    text = markdown(scores)
    if a.out is None:
        print(text)
    else:
        Path(a.out).parent.mkdir(parents=True, exist_ok=True)
        Path(a.out).write_text(text + "\n")
        print(f"wrote {a.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
