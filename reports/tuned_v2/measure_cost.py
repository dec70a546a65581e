"""Part 4 of the plan (README.md, "Order and cost"): what one batch of each remaining part costs
per training day, on the CPU (one thread, as ``grid.sh`` and ``part3.sh`` run, ``--workers 1``)
or on a GPU, so that the remaining wall time can be stated for this machine and for a lent GPU.

Each batch is the plan's own (its agent file, regimes and seeds), trained with the batched
engine for ``--days`` days and timed; the row gives seconds per training day of the whole batch
and the full part's hours at that rate. Not a run of the plan (nothing is stored):

    python reports/tuned_v2/measure_cost.py --days 20 --device cpu --out cost_cpu.md

Batches (``--batches`` picks by name):

- ``grid_gru``: ``gru_ppo_tuned_v2``, 7 regimes x the paper's 5 seeds (35 jobs), 5000 days;
- ``part3_gru``: ``gru_ppo_tuned_v2``, run5/run6 x seeds 3900-3909 (20 jobs), 5000 days (arms
  B, C and D cost alike: the same network; D's larger minibatch makes it cheaper);
- ``part3_ppo``: ``ppo_tuned_v2``, the same 20 jobs (arm A);
- ``sac_trial_bN``: one trial of the SAC study (``--stack 1``: 4 tuning regimes x 2 tuning
  seeds, 8 agents), 1000 days, with the replay minibatch N (32 or 256, the space's ends); the
  paper's ``sac`` file otherwise (the study's other knobs do not change the work per step);
  the part's hours are for the 22 trials left of 24;
- ``grid_sac``: the paper's ``sac`` file, 35 jobs, 5000 days (a stand-in for the v2 file that
  the study has not chosen yet: the minibatch it picks moves the cost).

The estimate is linear in days and leaves out the evaluation during training (forward passes
only); on a shared machine it is an order of magnitude, not a benchmark.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import torch as th

from nutribench.agents.config import load_agent_config
from nutribench.engine.train import train_batched

HERE = Path(__file__).resolve().parent
ALL_REGIMES = tuple(f"run{i}" for i in range(7))
PAPER_SEEDS = (0, 21, 9, 2003, 1997)
PART3 = [(r, s) for r in ("run5", "run6") for s in range(3900, 3910)]
TRIAL = [(r, s) for r in ("run0", "run2", "run4", "run5") for s in (101, 102)]
GRID = [(r, s) for r in ALL_REGIMES for s in PAPER_SEEDS]


def sac(batch_size: int | None = None):
    cfg = load_agent_config(Path(os.environ.get("NUTRIBENCH_ROOT", HERE.parents[1])) / "regimes/agents/sac.toml")
    return (
        cfg if batch_size is None else cfg.model_copy(update={"batch_size": batch_size, "learning_starts": batch_size})
    )


#: name -> (agent config, jobs, days of the part's one batch, batches of it left)
BATCHES = {
    "grid_gru": (lambda: load_agent_config(HERE / "agents/gru_ppo_tuned_v2.toml"), GRID, 5000, 1),
    "part3_gru": (lambda: load_agent_config(HERE / "agents/gru_ppo_tuned_v2.toml"), PART3, 5000, 3),
    "part3_ppo": (lambda: load_agent_config(HERE / "agents/ppo_tuned_v2.toml"), PART3, 5000, 1),
    "sac_trial_b32": (lambda: sac(32), TRIAL, 1000, 22),
    "sac_trial_b256": (lambda: sac(256), TRIAL, 1000, 22),
    "grid_sac": (sac, GRID, 5000, 1),
}
HEADER = (
    "| batch | jobs | device | days timed | wall s | s per training day | one batch (h) | batches left | part (h) |\n"
    "|---|---|---|---|---|---|---|---|---|\n"
)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=int, default=20, help="training days timed (GRU-PPO updates every 10)")
    ap.add_argument("--batches", default=",".join(BATCHES), help=f"comma-separated, of {', '.join(BATCHES)}")
    ap.add_argument("--device", default="cpu", help="cpu (the plan's runs), cuda or cuda:N")
    ap.add_argument("--out", type=Path, default=None)
    args = ap.parse_args()
    names = [n.strip() for n in args.batches.split(",") if n.strip()]
    unknown = [n for n in names if n not in BATCHES]
    if unknown:
        raise SystemExit(f"measure_cost.py: unknown batch {', '.join(unknown)}: known are {', '.join(BATCHES)}")
    th.set_num_threads(1)
    if args.device != "cpu":  # CUDA's start-up outside the rows
        train_batched(TRIAL[:1], sac(32), 1, device=args.device, return_agents=False)
    if args.out:
        args.out.write_text(HEADER)
    print(HEADER, end="", flush=True)
    for name in names:
        make, jobs, days, left = BATCHES[name]
        t0 = time.perf_counter()
        train_batched(jobs, make(), args.days, device=args.device, return_agents=False)
        wall = time.perf_counter() - t0
        per_day = wall / args.days
        one = per_day * days / 3600
        row = f"| {name} | {len(jobs)} | {args.device} | {args.days} | {wall:.1f} | {per_day:.2f} | {one:.2f} | {left} | {one * left:.1f} |\n"
        print(row, end="", flush=True)
        if args.out:
            with args.out.open("a") as f:
                f.write(row)


if __name__ == "__main__":
    main()
