"""The ladder study's cost estimate: how fast one of its batches trains at each observation level.

Trains, with the batched engine on the CPU (one thread, as a ``nutribench run --workers 1``
batch does), the plan's batch of one agent and level: one job per (regime run0/run3/run6,
seed of the plan), for ``--days`` training days, and prints the wall time per training day
of the whole batch and the 5000-day estimate. Before the plan's runs, not one of them:

    python reports/ladder/measure_speed.py --days 20 --out reports/ladder/speed.md

``--device cuda`` times the same batches on a GPU (the plan's runs are on the CPU; this only
says what a lent GPU would change), and ``--runs`` picks the (agent, level) pairs, e.g.
``--runs ppo:1,gru_ppo:4,sac_tuned:1`` (an agent file found through ``NUTRIBENCH_AGENTS``).
Each row is printed, and appended to ``--out``, as soon as it is measured.

The estimate is linear in days and leaves out the evaluation during training (``--eval-every
100``: 5 greedy validation days per 100 training days, forward passes only) and the final
evaluation; the machine's other users slow it by an unknown factor, so it is an order of
magnitude, not a benchmark.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch as th

from nutribench.config import load_env_config
from nutribench.engine.train import train_batched
from nutribench.env import NutriRLEnv

HERE = Path(__file__).resolve().parent
SEEDS = tuple(range(3800, 3810))
REGIMES = ("run0", "run3", "run6")
RUNS = "ppo:1,ppo:2,ppo:3,ppo:4,gru_ppo:1,gru_ppo:4"
HEADER = (
    "| agent | level | jobs | obs dims | device | days | wall s | s per training day of the batch | 5000 days (h) |\n"
    "|---|---|---|---|---|---|---|---|---|\n"
)


def regime(name: str, level: int):
    """The plan's regime file of ``name`` at ``level`` (1: the shipped file)."""
    return load_env_config(name if level == 1 else HERE / f"regimes_obs{level}" / f"{name}.toml")


def parse_runs(text: str) -> list[tuple[str, int]]:
    """``"ppo:1,gru_ppo:4"`` -> ``[("ppo", 1), ("gru_ppo", 4)]``; a bad item is one line, exit 2."""
    runs = []
    for item in text.split(","):
        algo, _, level = item.strip().partition(":")
        if not algo or level not in {"1", "2", "3", "4"}:
            raise SystemExit(f"measure_speed.py: --runs item {item!r} is not <agent>:<level 1-4> (e.g. ppo:1)")
        runs.append((algo, int(level)))
    return runs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=int, default=20)
    ap.add_argument("--runs", default=RUNS, help=f"(agent:level) pairs, comma-separated (default {RUNS})")
    ap.add_argument("--device", default="cpu", help="cpu (the plan's), cuda or cuda:N")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    runs = parse_runs(args.runs)
    th.set_num_threads(1)
    if args.out:
        args.out.write_text(HEADER)
    print(HEADER, end="", flush=True)
    for algo, level in runs:
        jobs = [(regime(name, level), seed) for name in REGIMES for seed in SEEDS]
        dims = NutriRLEnv(jobs[0][0]).observation_space.shape[0]
        t0 = time.perf_counter()
        train_batched(jobs, algo, args.days, device=args.device)
        wall = time.perf_counter() - t0
        per_day = wall / args.days
        row = (
            f"| {Path(algo).stem} | {level} | {len(jobs)} | {dims} | {args.device} | {args.days} | {wall:.1f} | {per_day:.2f} | "
            f"{per_day * 5000 / 3600:.1f} |\n"
        )
        print(row, end="", flush=True)
        if args.out:
            with args.out.open("a") as f:
                f.write(row)


if __name__ == "__main__":
    main()
