"""What GRU-PPO's memory costs on run0 and buys in the delayed regimes: a diagnostic, not an agent.

Trains ``gru_ppo.toml`` (batched engine by default, or SB3's) twice over the same seeds and budget, once as
it is (the GRU state carried from step to step within a day, as the paper describes) and once
with the state reset before every step (no memory: length-1 sequences with no carried state,
as a published implementation feeds them). Everything else is identical: file, seeds, initial
weights, food days, evaluation days. Both are evaluated greedily on the seeds' fixed
evaluation days and summarised as ``nutribench bench learn`` does (share of the never ->
planner gap closed).

    python reports/gru_memory/without_memory.py --regimes run0 --seeds 0,1,2,3,4,5,6,7,8,9

About 70 s per 10 seeds x regime x variant on one core of the 2-core machine (``--engine sb3``:
the reference engine, one agent after another, about 1 min per agent). The memoryless
variant is made by patching three functions for the duration of its run (acting, the
update's replay of days, and the SB3 policy, which the SB3 engine trains and both engines
evaluate with); see :func:`no_memory`.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import torch as th

import nutribench.agents.gru_ppo.policy as sb3_policy
import nutribench.engine.gru_ppo as stacked
from nutribench.agents import load_agent_config
from nutribench.cli.common import UserError, split_csv
from nutribench.config import list_regimes
from nutribench.scheduler.grid import parse_seeds

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # the developer's benchmarks
from learn import batched_runs, markdown_table, one_run, summarize_runs  # noqa: E402 (benchmarks/learn.py)


@contextmanager
def no_memory() -> Iterator[None]:
    """GRU-PPO with its hidden state zeroed before every step, in acting, training and evaluation."""
    sequences = stacked.StackedGRUActorCritic.sequences
    act = stacked.RecurrentActor.__call__
    unroll = sb3_policy.GRUActorCriticPolicy.unroll

    def sequences_of_single_steps(self, obs: th.Tensor) -> tuple[th.Tensor, th.Tensor]:
        k, s, t, d = obs.shape  # every step its own sequence, from the zero state
        logits, values = sequences(self, obs.reshape(k, s * t, 1, d))
        return logits.reshape(k, s, t, -1), values.reshape(k, s, t)

    def act_from_zero(self, obs: th.Tensor, starts: th.Tensor, advance: bool = True):
        return act(self, obs, th.ones_like(starts), advance)

    def unroll_from_zero(self, obs: th.Tensor, state, episode_starts: th.Tensor):
        return unroll(self, obs, state, th.ones_like(episode_starts))

    stacked.StackedGRUActorCritic.sequences = sequences_of_single_steps
    stacked.RecurrentActor.__call__ = act_from_zero
    sb3_policy.GRUActorCriticPolicy.unroll = unroll_from_zero
    try:
        yield
    finally:
        stacked.StackedGRUActorCritic.sequences = sequences
        stacked.RecurrentActor.__call__ = act
        sb3_policy.GRUActorCriticPolicy.unroll = unroll


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--regimes", default="run0", help="comma-separated regimes (default run0)")
    parser.add_argument("--seeds", default="0,1,2,3,4,5,6,7,8,9", help="comma-separated training seeds")
    parser.add_argument("--episodes", type=int, default=500, help="training days (default 500)")
    parser.add_argument(
        "--engine",
        choices=("batched", "sb3"),
        default="batched",
        help="batched (all seeds and regimes at once) or sb3 (the reference engine, in turn)",
    )
    args = parser.parse_args()
    try:  # the CLI's own parsing, and its one-line errors
        regimes, seeds = split_csv(args.regimes, list_regimes(), "regime"), list(parse_seeds(args.seeds))
    except UserError as e:
        parser.error(str(e))
    th.set_num_threads(1)
    cfg = load_agent_config("gru_ppo")

    def runs() -> list:
        if args.engine == "batched":
            return batched_runs(cfg, regimes, seeds, args.episodes, 10)
        return [one_run(cfg, r, s, args.episodes, 10) for r in regimes for s in seeds]

    rows = summarize_runs(runs())
    with no_memory():
        memoryless = summarize_runs(runs())
    for row in memoryless:
        row["algo"] = f"{row['algo']} without memory"
    print(markdown_table(rows + memoryless))


if __name__ == "__main__":
    main()
