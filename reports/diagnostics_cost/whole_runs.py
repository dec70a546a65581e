"""The training diagnostics' cost from whole runs (this study's first bench, once ``nutribench
bench train --diagnostics-cost``): each repeat trains the same job three times, with the
diagnostics, without (``train(..., diagnostics=False)``) and without again (the A/A control:
the bench's own resolution), the three in their 6 orders in turn, so that 6k repeats balance
which runs first::

    python reports/diagnostics_cost/whole_runs.py --algos mc --days 40 --repeats 15

The cost is 1 - the median over repeats of (seconds without / seconds with), paired per repeat,
with its 95 % bootstrap interval over the repeats (``paired_cost`` of ``benchmarks/cost_stats.py``).
Both arms without the diagnostics still build the same model: what an update records for
itself (the gradient norm it keeps, ``.item()`` reads of its losses) is in every arm, and only
the profile counts it. A machine whose speed drifts over minutes moves one arm's run and not
the other's: ``lockstep.py`` trains the arms a day each in turn instead.
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from lockstep import ORDERS  # this folder's: the script runs by path

from nutribench.bench.throughput import bench_config

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # the cost statistics (developer code)
from cost_stats import paired_cost  # noqa: E402


def bench_diagnostics_cost(
    algos: Sequence[str], regime: str = "run0", episodes: int = 100, repeats: int = 3, seed: int = 0
) -> list[dict]:
    """Per algorithm (its :func:`~nutribench.bench.throughput.bench_config`): ``steps_per_s``
    with the diagnostics and ``steps_per_s_without`` (medians), ``diagnostics_cost`` with
    ``diagnostics_cost_ci``, and ``aa_cost`` with ``aa_cost_ci`` (without against without again)."""
    from nutribench.agents import api

    def timed(cfg, diagnostics: bool) -> float:
        t0 = time.perf_counter()
        api.train(regime, cfg, seed=seed, episodes=episodes, diagnostics=diagnostics)
        return time.perf_counter() - t0

    rows = []
    for algo in algos:
        cfg = bench_config(algo)
        api.train(regime, cfg, seed=seed, episodes=1)  # untimed: the first training pays one-off imports and set-up
        with_, without, again = [], [], []
        arms = [(with_, True), (without, False), (again, False)]
        for i in range(repeats):
            for k in ORDERS[i % len(ORDERS)]:
                arms[k][0].append(timed(cfg, arms[k][1]))
        row = {
            "algo": algo,
            "steps_per_s": episodes * 50 / statistics.median(with_),
            "steps_per_s_without": episodes * 50 / statistics.median(without),
        }
        for key, (a, b) in (("diagnostics_cost", (with_, without)), ("aa_cost", (again, without))):
            cost, lo, hi = paired_cost(a, b)
            row[key], row[f"{key}_ci"] = cost, (lo, hi)
        rows.append(row)
    return rows


def share_ci(row: dict, key: str) -> str:
    """``row[key]`` and its interval ``row[key + "_ci"]`` as percentages: "+1.2 % [-0.5, +3.0]"."""
    lo, hi = row[f"{key}_ci"]
    return f"{100 * row[key]:+.1f} % [{100 * lo:+.1f}, {100 * hi:+.1f}]"


def main(argv: Sequence[str] | None = None) -> int:
    import argparse

    from rich.console import Console
    from rich.table import Table

    from nutribench.agents.registry import paper_names
    from nutribench.config import load_env_config

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--algos", default="all", help="'all' or comma-separated algorithms")
    ap.add_argument("--regime", default="run0")
    ap.add_argument("--days", type=int, default=100, help="training days per timed run")
    ap.add_argument("--repeats", type=int, default=3, help="timed repeats of the three arms")
    args = ap.parse_args(argv)
    names = paper_names() if args.algos == "all" else [a.strip() for a in args.algos.split(",")]
    unknown = sorted(set(names) - set(paper_names()))
    if unknown or args.days < 1 or args.repeats < 1:
        what = (
            f"unknown algorithm {unknown[0]!r} (known: {', '.join(paper_names())})"
            if unknown
            else "--days and --repeats: 1 or more"
        )
        print(f"whole_runs.py: {what}", file=sys.stderr)
        return 2
    load_env_config(args.regime)
    table = Table(
        "algo",
        "env-steps/s (median)",
        "without diagnostics, env-steps/s",
        "diagnostics' cost (paired median) [95 % CI]",
        "A/A: without vs without again [95 % CI]",
        title=f"training diagnostics' cost, {args.regime}, {args.days} days x {args.repeats}",
    )
    for r in bench_diagnostics_cost(names, regime=args.regime, episodes=args.days, repeats=args.repeats):
        table.add_row(
            r["algo"],
            f"{r['steps_per_s']:,.0f}",
            f"{r['steps_per_s_without']:,.0f}",
            share_ci(r, "diagnostics_cost"),
            share_ci(r, "aa_cost"),
        )
    Console().print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
