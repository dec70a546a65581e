"""Lockstep timing: the arms of a paired benchmark trained side by side, a day each in turn
(this study's bench, once ``nutribench bench train --diagnostics-cost --lockstep``)::

    python reports/diagnostics_cost/lockstep.py --algos ppo --days 1200 --block 10

``whole_runs.py`` (once ``bench train --diagnostics-cost``) times whole runs one after another, so a machine whose speed drifts over minutes (a shared one)
moves one arm's run and not the other's: on this project's 2-core machine two identical runs
differed by 2-6 % (its A/A control), more than the 3 % the diagnostics may cost.

Here the three arms (with the diagnostics, without, without again: the A/A control) are three
training runs in one process, each in its own thread, and only one runs at a time: each arm
trains one day (its env's day end, ``train``'s ``on_episode``), hands over, and waits for
its turn in the next round; the rounds take the 6 orders of the arms in turn. A round's three
segments run within a second or two of each other, so a drift of the machine reaches all
three alike, and the pairing is by segment: the same seed's day in every arm (the
diagnostics change no number of training, which :func:`bench_diagnostics_lockstep` checks:
``identical``, from :func:`same_days`).

Each arm keeps its own global random state (Python's, NumPy's, torch's: SB3 samples actions
and shuffles minibatches from them), restored when its turn starts and saved when it ends,
so an arm trains exactly what it would train alone. Each segment is timed in wall-clock and
in the thread's CPU time (``time.thread_time``: torch runs on the calling thread at
``set_num_threads(1)``), which leaves out time the machine gave to other processes.

What lockstep changes: every segment starts with caches warm with another arm's data, in
every arm alike, so the cost's share is of a slightly longer base time (understated by that
refill, microseconds against a day of 50-100 ms). And the arms share one process: Python's
garbage collector and the memory allocator. Garbage one arm makes may be collected in another
arm's turn, and a full collection walks all three arms' objects, which spreads a cost that
is made of garbage over the arms and pulls its estimate toward 0 (the diagnostics make little:
a dict a row, floats an update).
"""

from __future__ import annotations

import itertools
import random
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch as th

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # the cost statistics (developer code)
from cost_stats import paired_cost, total_cost  # noqa: E402

#: A run of one arm: called with the day-end callback it must call after each training day.
ArmRun = Callable[[Callable[[dict], None]], Any]


def seamless_orders(n: int) -> list[tuple[int, ...]]:
    """Every order of ``n`` arms, arranged so that no order starts with the arm that ended the
    one before (the last order wrapping round to the first): no arm ever runs twice in a row,
    in lockstep with warm caches of its own. Lexicographic order has two such seams for 3 arms
    (``(0, 2, 1) -> (1, 0, 2)``, ``(2, 1, 0) -> (0, 1, 2)``). Two arms cannot avoid one; then the
    plain order is returned."""
    perms = list(itertools.permutations(range(n)))

    def extend(path: list[tuple[int, ...]], left: list[tuple[int, ...]]) -> list[tuple[int, ...]] | None:
        if not left:
            return path if path[-1][-1] != path[0][0] else None
        for i, p in enumerate(left):
            if p[0] != path[-1][-1]:
                found = extend(path + [p], left[:i] + left[i + 1 :])
                if found is not None:
                    return found
        return None

    return (extend(perms[:1], perms[1:]) if n > 2 else None) or perms


#: The orders of the three arms (with, without, again), here and in ``whole_runs.py``: 6 rounds
#: put each arm before each other equally often, each arm first, second and last twice, and no
#: arm twice in a row across a round's end.
ORDERS = seamless_orders(3)


class _Aborted(BaseException):
    """Raised in a waiting arm when another arm failed: it stops without running on."""


@dataclass
class Arm:
    """One arm's timings: ``wall[i]`` and ``cpu[i]`` are the seconds of its segment ``i``
    (segment 0 runs from the start of the run to the end of day 0, segment ``i`` from the end
    of day ``i - 1`` to the end of day ``i``; the last, after the last day, to the run's end),
    ``days`` the metrics each day ended with."""

    name: str
    wall: list[float] = field(default_factory=list)
    cpu: list[float] = field(default_factory=list)
    days: list[dict] = field(default_factory=list)
    error: BaseException | None = None
    finished: bool = False
    go: threading.Event = field(default_factory=threading.Event)
    _rng: tuple = ()
    _t0: tuple[float, float] = (0.0, 0.0)


def _save_rng() -> tuple:
    return random.getstate(), np.random.get_state(), th.get_rng_state()


def _restore_rng(state: tuple) -> None:
    random.setstate(state[0])
    np.random.set_state(state[1])
    th.set_rng_state(state[2])


def lockstep(runs: dict[str, ArmRun]) -> list[Arm]:
    """Run ``runs`` (name -> run) side by side, one segment (a training day) each in turn,
    the rounds in every order of the arms in turn, no arm twice in a row across a round's end
    (:func:`seamless_orders`; three arms: :data:`ORDERS`);
    return each arm's timings. Every arm starts from the caller's random state.

    An arm that ends before the others sits out the rounds left. An error in an arm stops
    every arm and is raised here."""
    handback = threading.Event()
    abort = threading.Event()
    arms = [Arm(name) for name in runs]
    orders = seamless_orders(len(arms))
    rng = _save_rng()  # the caller's random state: every arm's first, and given back at the end
    for a in arms:
        a._rng = rng

    def start(arm: Arm) -> None:
        arm.go.wait()
        arm.go.clear()
        if abort.is_set():
            raise _Aborted
        _restore_rng(arm._rng)
        arm._t0 = (time.perf_counter(), time.thread_time())

    def stop(arm: Arm) -> None:
        wall, cpu = time.perf_counter(), time.thread_time()
        arm.wall.append(wall - arm._t0[0])
        arm.cpu.append(cpu - arm._t0[1])
        arm._rng = _save_rng()
        handback.set()

    def body(arm: Arm, run: ArmRun) -> None:
        def day_end(metrics: dict) -> None:
            arm.days.append(metrics)
            stop(arm)
            start(arm)

        try:
            start(arm)
            run(day_end)
        except _Aborted:
            pass
        except BaseException as e:  # noqa: BLE001 - handed to the caller's thread
            arm.error = e
        finally:
            arm.finished = True
            if not abort.is_set() and arm.error is None:
                stop(arm)  # the last segment: after the last day, to the run's end
            else:
                handback.set()

    threads = [threading.Thread(target=body, args=(a, runs[a.name]), daemon=True) for a in arms]
    for t in threads:
        t.start()
    try:
        r = 0
        while not all(a.finished for a in arms):
            for k in orders[r % len(orders)]:
                arm = arms[k]
                if arm.finished:
                    continue
                handback.clear()
                arm.go.set()
                while not handback.wait(1.0):
                    if not threads[k].is_alive():
                        raise RuntimeError(f"lockstep: arm {arm.name!r} ended without handing back")
                if arm.error is not None:
                    raise arm.error
            r += 1
    finally:
        abort.set()
        for a in arms:
            a.go.set()
        for t in threads:
            t.join()
        _restore_rng(rng)
    return arms


def blocks(seconds: Sequence[float], size: int) -> np.ndarray:
    """Consecutive sums of ``size`` segments (the last block may be shorter): with ``size`` a
    PPO rollout's days, every block holds one update."""
    s = np.asarray(seconds, dtype=float)
    return np.add.reduceat(s, np.arange(0, len(s), size))


def same_days(a: Arm, b: Arm, key: str = "return") -> bool:
    """Whether two arms trained the same days (their ``key`` equal, day by day)."""
    return len(a.days) == len(b.days) and all(x[key] == y[key] for x, y in zip(a.days, b.days))


def lockstep_cost(with_: Arm, without: Arm, again: Arm, size: int, clock: str = "wall") -> dict:
    """The diagnostics' cost and the A/A control from one lockstep run on ``clock`` ("wall" or
    "cpu"): ``total_cost`` (``benchmarks/cost_stats.py``) of (with, without) and of (again,
    without) over blocks of ``size`` segments, and ``median_cost`` (:func:`paired_cost`, the
    median of the blocks' ratios, which weighs a block without an update like one with)."""
    w, wo, ag = (blocks(getattr(a, clock), size) for a in (with_, without, again))
    cost, aa = total_cost(w, wo), total_cost(ag, wo)
    return {
        "cost": cost[0],
        "cost_ci": cost[1:],
        "aa": aa[0],
        "aa_ci": aa[1:],
        "median_cost": paired_cost(w, wo)[0],
        "blocks": len(w),
    }


def bench_diagnostics_lockstep(
    algos: Sequence[str], regime: str = "run0", episodes: int = 300, block: int = 10, seed: int = 0
) -> list[dict]:
    """This script's bench: for each algorithm, its shipped config
    (:func:`~nutribench.bench.throughput.bench_config`) trained ``episodes`` days three times
    in lockstep (with the diagnostics, without, without again), and :func:`lockstep_cost` on
    the wall clock and on CPU time, paired by blocks of ``block`` days. ``identical``: the three
    arms trained the same days (the pairing is of equal work)."""
    from nutribench.agents.api import train
    from nutribench.bench.throughput import bench_config

    rows = []
    for algo in algos:
        cfg = bench_config(algo)
        train(regime, cfg, seed=seed, episodes=1)  # untimed: one-off imports and set-up

        def arm(diagnostics: bool, cfg=cfg) -> ArmRun:
            return lambda day_end: train(
                regime, cfg, seed=seed, episodes=episodes, on_episode=day_end, diagnostics=diagnostics
            )

        w, wo, ag = lockstep({"with": arm(True), "without": arm(False), "again": arm(False)})
        row: dict[str, Any] = {
            "algo": algo,
            "days": episodes,
            "identical": same_days(w, wo) and same_days(ag, wo),
            "steps_per_s": episodes * 50 / sum(w.wall),
            "steps_per_s_without": episodes * 50 / sum(wo.wall),
        }
        for clock in ("wall", "cpu"):
            row[clock] = lockstep_cost(w, wo, ag, block, clock)
        rows.append(row)
    return rows


def share_ci(row: dict, key: str) -> str:
    """``row[key]`` and its interval ``row[key + "_ci"]`` as percentages: "+1.2 % [-0.5, +3.0]"."""
    lo, hi = row[f"{key}_ci"]
    return f"{100 * row[key]:+.1f} % [{100 * lo:+.1f}, {100 * hi:+.1f}]"


def main(argv: Sequence[str] | None = None) -> int:
    """The table and notes ``bench train --diagnostics-cost --lockstep`` printed."""
    import argparse

    from rich.console import Console
    from rich.table import Table

    from nutribench.agents.registry import paper_names
    from nutribench.config import load_env_config

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--algos", default="all", help="'all' or comma-separated algorithms")
    ap.add_argument("--regime", default="run0")
    ap.add_argument("--days", type=int, default=100, help="training days of each arm")
    ap.add_argument("--block", type=int, default=10, help="days per paired block (PPO's rollout: 10)")
    args = ap.parse_args(argv)
    names = paper_names() if args.algos == "all" else [a.strip() for a in args.algos.split(",")]
    unknown = sorted(set(names) - set(paper_names()))
    if unknown or args.days < 1 or args.block < 1:
        what = (
            f"unknown algorithm {unknown[0]!r} (known: {', '.join(paper_names())})"
            if unknown
            else "--days and --block: 1 or more"
        )
        print(f"lockstep.py: {what}", file=sys.stderr)
        return 2
    load_env_config(args.regime)
    console = Console()
    table = Table(
        "algo",
        "clock",
        "cost: share of the time [95 % CI]",
        "A/A: without vs without again [95 % CI]",
        "median of the blocks' ratios",
        title=f"diagnostics' cost in lockstep, {args.regime}, {args.days} days per arm, blocks of {args.block} days",
    )
    notes = []
    for r in bench_diagnostics_lockstep(names, regime=args.regime, episodes=args.days, block=args.block):
        for clock, label in (("wall", "wall"), ("cpu", "CPU")):
            c = r[clock]
            table.add_row(r["algo"], label, share_ci(c, "cost"), share_ci(c, "aa"), f"{100 * c['median_cost']:+.1f} %")
        same = "yes" if r["identical"] else "NO (the pairing is not of equal work)"
        notes.append(
            f"{r['algo']}: {r['wall']['blocks']} blocks; the three arms trained the same days: {same}; "
            f"env-steps/s {r['steps_per_s']:,.0f} with, {r['steps_per_s_without']:,.0f} without"
        )
    console.print(table)
    for line in notes:
        console.print(line, highlight=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())
