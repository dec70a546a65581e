"""A positive control for the lockstep bench: does it find a cost that is known to be there?

Four arms of SB3 PPO on run0 in lockstep (``lockstep.py``, this folder's): with the diagnostics,
without, without again (the A/A control), and without the diagnostics but with a busy wait of
``--wait-ms`` added to every training day (inside the day's timed segment). The known cost of
the last arm is the waits' share of its time, ``n_days x wait / (its total)``; the bench's
estimate of it (``total_cost`` over blocks of 10 days, against the arm without) should hold it
in its interval, as the A/A control's should hold 0.

    python reports/diagnostics_cost/positive_control.py --days 1200 --wait-ms 3
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from lockstep import blocks, lockstep, same_days  # this folder's: the script runs by path

from nutribench.agents.api import train
from nutribench.bench.throughput import bench_config

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # the cost statistics (developer code)
from cost_stats import total_cost  # noqa: E402


def busy(seconds: float) -> None:
    t = time.perf_counter()
    while time.perf_counter() - t < seconds:
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--days", type=int, default=1200)
    ap.add_argument("--wait-ms", type=float, default=3.0)
    ap.add_argument("--block", type=int, default=10)
    args = ap.parse_args()
    cfg, wait = bench_config("ppo"), args.wait_ms / 1000

    def arm(diagnostics: bool, waits: bool = False):
        def run(day_end):
            def slow_day_end(metrics: dict) -> None:
                busy(wait)
                day_end(metrics)

            train(
                "run0",
                cfg,
                seed=0,
                episodes=args.days,
                on_episode=slow_day_end if waits else day_end,
                diagnostics=diagnostics,
            )

        return run

    train("run0", cfg, seed=0, episodes=1)  # untimed: one-off set-up
    arms = lockstep({"with": arm(True), "without": arm(False), "again": arm(False), "waits": arm(False, waits=True)})
    w, wo, ag, wt = arms
    print(f"PPO, run0, {args.days} days per arm, blocks of {args.block} days, wait {args.wait_ms} ms a day")
    print(f"the four arms trained the same days: {same_days(w, wo) and same_days(ag, wo) and same_days(wt, wo)}")
    for clock in ("wall", "cpu"):
        b = {a.name: blocks(getattr(a, clock), args.block) for a in arms}
        known = args.days * wait / b["waits"].sum()
        for name, label in (("with", "diagnostics"), ("again", "A/A"), ("waits", "known wait")):
            c, lo, hi = total_cost(list(b[name]), list(b["without"]))
            print(f"{clock:4} {label:12} {100 * c:+.2f} % [{100 * lo:+.2f}, {100 * hi:+.2f}]", end="")
            print(f"   (known: {100 * known:.2f} %)" if name == "waits" else "")
    print(f"median seconds per day segment, without: {np.median(wo.wall):.4f}")


if __name__ == "__main__":
    main()
