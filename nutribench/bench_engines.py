"""``nutribench bench engines``: do the batched engine's agents learn what the SB3 agents
learn? Both engines train the same agent config on the same regimes, seeds and budget;
each trained agent plays greedily on its seed's fixed evaluation days; per (algorithm,
regime, engine) the table gives the IQM of the evaluation returns with a 95 % percentile
bootstrap interval over seeds (rliable's habit), the share of the never -> planner gap,
and the wall time. The two engines' random streams differ (see
:mod:`nutribench.engine.train`), so the comparison is of distributions: the intervals of
the two engines must overlap.

The SB3 engine trains one job per process on a process pool (one per core); the batched
engine trains all of an algorithm's jobs in one process, on one core (or on ``device``).
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from typing import Any

import numpy as np

from nutribench.bench_learn import LearnRun, batched_runs, learn_benchmark, summarize
from nutribench.engine import BATCHED_ALGOS
from nutribench.report.stats import iqm_bootstrap_ci

ENGINES = ("sb3", "batched")


def bench_engines(algos: Iterable[str] = BATCHED_ALGOS, regimes: Iterable[str] = ("run0", "run6"),
                  seeds: Iterable[int] = (0, 1, 2, 3, 4), episodes: int = 500, eval_episodes: int = 10,
                  workers: int | None = None, device: str = "cpu") -> list[dict[str, Any]]:  # fmt: skip
    """One row per (algorithm, regime, engine), and per (algorithm, regime) whether the two
    engines' intervals overlap (``overlap``, on the batched row)."""
    algos, regimes, seeds = list(algos), list(regimes), list(seeds)
    unknown = [a for a in algos if a not in BATCHED_ALGOS]
    if unknown:
        raise ValueError(f"the batched engine does not train {', '.join(unknown)} yet (it trains {', '.join(BATCHED_ALGOS)})")
    runs: dict[str, list[LearnRun]] = {"sb3": [], "batched": []}
    start = time.perf_counter()
    runs["sb3"] = learn_benchmark(algos, regimes, seeds, budgets={}, default_budget=episodes, eval_episodes=eval_episodes, workers=workers)
    sb3_wall = time.perf_counter() - start
    start = time.perf_counter()
    for algo in algos:
        runs["batched"] += batched_runs(algo, regimes, seeds, episodes, eval_episodes, device)
    batched_wall = time.perf_counter() - start
    rows = []
    for algo in algos:
        for regime in regimes:
            pair = []
            for engine in ENGINES:
                rs = [r for r in runs[engine] if r.algo == algo and r.regime == regime]
                by_seed = [np.array([e["return"] for e in r.eval_rows]) for r in rs]
                point, lo, hi = iqm_bootstrap_ci(by_seed)
                learned = summarize(rs)[0]  # the gap, foods and wall time as bench learn states them
                row = {"algo": algo, "regime": regime, "engine": engine, "seeds": len(rs), "episodes": episodes,
                       "iqm": point, "ci_low": lo, "ci_high": hi, "gap_closed": learned["gap_closed"],
                       "foods": learned["foods"], "wall_seconds_per_job": learned["wall_seconds"], "overlap": None}  # fmt: skip
                pair.append(row)
            sb3, batched = pair
            batched["overlap"] = bool(sb3["ci_low"] <= batched["ci_high"] and batched["ci_low"] <= sb3["ci_high"])
            rows += pair
    for r in rows:
        r["total_wall_seconds"] = sb3_wall if r["engine"] == "sb3" else batched_wall
    return rows


COLUMNS = ("algo", "regime", "engine", "seeds", "days", "IQM return [95 % CI]", "gap closed", "foods",
           "wall s per job", "intervals overlap")  # fmt: skip


def row_cells(r: dict[str, Any]) -> list[str]:
    return [r["algo"], r["regime"], r["engine"], str(r["seeds"]), str(r["episodes"]),
            f"{r['iqm']:.2f} [{r['ci_low']:.2f}, {r['ci_high']:.2f}]", f"{100 * r['gap_closed']:.0f} %", f"{r['foods']:.2f}",
            f"{r['wall_seconds_per_job']:.1f}", "" if r["overlap"] is None else ("yes" if r["overlap"] else "NO")]  # fmt: skip


def markdown_table(rows: list[dict[str, Any]]) -> str:
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    return "\n".join(lines + ["| " + " | ".join(row_cells(r)) + " |" for r in rows])
