"""What the evaluation during training costs (this folder's bench, once ``nutribench bench train
--eval-every N``)::

    python reports/eval_cost/evalcost.py --algos ppo,mc --days 100 --repeats 4 --eval-every 50
    python reports/eval_cost/evalcost.py --algos ppo,mc --engine batched --days 50 --repeats 2 --eval-every 50

Each
repeat trains the same job (SB3 engine) or batch (batched engine: 7 regimes x 5 seeds at
once) twice, with and without ``eval_every``, in alternating order; the cost is the share of
the training time the evaluations take, paired per repeat
(``paired_cost`` of ``benchmarks/cost_stats.py``, 95 % bootstrap interval over the repeats),
on the wall clock and on the process's CPU time (which other work on a shared machine moves
less). The two arms train identically (tests/test_validation.py), so the difference is the
evaluations alone."""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Sequence
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "benchmarks"))  # the cost statistics (developer code)
from cost_stats import paired_cost  # noqa: E402


def _timed(algo: str, engine: str, regime: str, episodes: int, seed: int, **evaluation: int) -> tuple[float, float]:
    """Wall and CPU seconds of one training of ``algo`` (``evaluation``: ``eval_every`` and
    ``val_episodes``, or none)."""
    from nutribench import SHIPPED_REGIMES
    from nutribench.agents.api import train
    from nutribench.engine.train import train_batched

    t0, c0 = time.perf_counter(), time.process_time()
    if engine == "batched":
        train_batched([(r, s) for r in SHIPPED_REGIMES for s in range(5)], algo, episodes, **evaluation)
    else:
        train(regime, algo, seed=seed, episodes=episodes, **evaluation)
    return time.perf_counter() - t0, time.process_time() - c0


def _one_evaluation_cpu(algo: str, engine: str, regime: str, n: int, seed: int, times: int = 10) -> float:
    """CPU seconds of one evaluation alone (the median of ``times``): the SB3 engine's
    ``evaluate`` of an agent on its ``n`` validation days; the batched engine's play of the
    K = 35 agents' (untrained weights: the same work)."""
    from nutribench import SHIPPED_REGIMES
    from nutribench.agents.api import evaluate, train, validation_food_streams
    from nutribench.agents.config import load_agent_config
    from nutribench.agents.registry import batched_class
    from nutribench.engine.envs import AgentEnvs
    from nutribench.engine.evaluate import BatchValidator

    if engine == "batched":
        cfg = load_agent_config(algo)
        envs = AgentEnvs([(r, s) for r in SHIPPED_REGIMES for s in range(5)], cfg.normalize_obs)
        algorithm, validator = batched_class(cfg.algo)(cfg, envs, "cpu"), BatchValidator(envs, 1, n)
        play = lambda: validator.play(algorithm.greedy())  # noqa: E731
    else:
        agent, days = train(regime, algo, seed=seed, episodes=1), validation_food_streams(regime, seed, n)
        play = lambda: evaluate(agent, regime, days, record_steps=False)  # noqa: E731
    cpu = []
    for _ in range(times):
        c0 = time.process_time()
        play()
        cpu.append(time.process_time() - c0)
    return statistics.median(cpu)


def bench_eval_cost(
    algos: list[str],
    regime: str = "run0",
    episodes: int = 100,
    repeats: int = 4,
    eval_every: int = 50,
    val_episodes: int = 5,
    engine: str = "sb3",
    seed: int = 0,
) -> list[dict]:
    """Per algorithm: the median wall seconds with and without the evaluations, the
    evaluations made per run, and ``cost`` (with ``cost_ci``): their share of the training
    time on the wall clock; ``cpu_cost`` (``cpu_cost_ci``) the same in CPU time;
    ``evaluation_cpu_s``: one evaluation timed alone, and ``component_cost``: the share of
    the training's CPU time (the median without) the run's evaluations take at that time each."""
    rows = []
    evaluation = {"eval_every": eval_every, "val_episodes": val_episodes}
    for algo in algos:
        _timed(algo, engine, regime, 1, seed)  # untimed: one-off imports and set-up
        with_, without = [], []
        for i in range(repeats):
            for arm in (with_, without) if i % 2 == 0 else (without, with_):
                arm.append(_timed(algo, engine, regime, episodes, seed, **(evaluation if arm is with_ else {})))
        row = {
            "algo": algo,
            "engine": engine,
            "with_s": statistics.median(w for w, _ in with_),
            "without_s": statistics.median(w for w, _ in without),
            "evaluations": episodes // eval_every,
        }
        for key, k in (("cost", 0), ("cpu_cost", 1)):
            cost, lo, hi = paired_cost([t[k] for t in with_], [t[k] for t in without])
            row[key], row[f"{key}_ci"] = cost, (lo, hi)
        row["evaluation_cpu_s"] = one = _one_evaluation_cpu(algo, engine, regime, val_episodes, seed)
        spent = row["evaluations"] * one
        row["component_cost"] = spent / (statistics.median(c for _, c in without) + spent)
        rows.append(row)
    return rows


def share_ci(row: dict, key: str) -> str:
    """``row[key]`` and its interval ``row[key + "_ci"]`` as percentages: "+1.2 % [-0.5, +3.0]"."""
    lo, hi = row[f"{key}_ci"]
    return f"{100 * row[key]:+.1f} % [{100 * lo:+.1f}, {100 * hi:+.1f}]"


def main(argv: Sequence[str] | None = None) -> int:
    """The table ``bench train --eval-every`` printed."""
    import argparse

    from rich.console import Console
    from rich.table import Table

    from nutribench.agents.registry import batched_names, paper_names
    from nutribench.config import load_env_config

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--algos", default="all", help="'all' or comma-separated algorithms")
    ap.add_argument("--regime", default="run0", help="the SB3 engine's regime (batched: all seven, 5 seeds)")
    ap.add_argument("--days", type=int, default=100, help="training days per timed run")
    ap.add_argument("--repeats", type=int, default=4)
    ap.add_argument("--eval-every", type=int, default=50, help="an evaluation every so many training days")
    ap.add_argument("--val-episodes", type=int, default=5, help="validation days per evaluation")
    ap.add_argument("--engine", default="sb3", choices=("sb3", "batched"))
    args = ap.parse_args(argv)
    known = batched_names() if args.engine == "batched" else paper_names()
    names = list(known) if args.algos == "all" else [a.strip() for a in args.algos.split(",")]
    unknown = sorted(set(names) - set(known))
    problem = None
    if unknown:
        problem = f"unknown algorithm {unknown[0]!r} for the {args.engine} engine (known: {', '.join(known)})"
    elif min(args.days, args.repeats, args.eval_every, args.val_episodes) < 1:
        problem = "--days, --repeats, --eval-every and --val-episodes: 1 or more"
    elif args.eval_every > args.days:
        problem = f"--eval-every {args.eval_every}: more than --days {args.days}, no evaluation would be timed"
    if problem:
        print(f"evalcost.py: {problem}", file=sys.stderr)
        return 2
    load_env_config(args.regime)
    where = "K = 35" if args.engine == "batched" else args.regime
    title = (
        f"evaluation every {args.eval_every} days on {args.val_episodes} validation days, {args.engine} engine "
        f"({where}), {args.days} days x {args.repeats}"
    )
    heads = ["algo", "without (s)", "with (s)", "evaluations", "cost, wall [95 % CI]", "cost, CPU", "one alone (CPU s)"]
    table = Table(*heads, "its share", title=title)
    rows = bench_eval_cost(names, args.regime, args.days, args.repeats, args.eval_every, args.val_episodes, args.engine)
    for r in rows:
        times = [f"{r['without_s']:.2f}", f"{r['with_s']:.2f}", str(r["evaluations"])]
        alone = [f"{r['evaluation_cpu_s']:.3f}", f"{100 * r['component_cost']:.1f} %"]
        table.add_row(r["algo"], *times, share_ci(r, "cost"), share_ci(r, "cpu_cost"), *alone)
    Console().print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
