"""``nutribench bench train --eval-every N``: what the evaluation during training costs. Each
repeat trains the same job (SB3 engine) or batch (batched engine: 7 regimes x 5 seeds at
once) twice, with and without ``eval_every``, in alternating order; the cost is the share of
the training time the evaluations take, paired per repeat
(:func:`~nutribench.bench.paired.paired_cost`, 95 % bootstrap interval over the repeats),
on the wall clock and on the process's CPU time (which other work on a shared machine moves
less). The two arms train identically (tests/test_validation.py), so the difference is the
evaluations alone."""

from __future__ import annotations

import statistics
import time

from nutribench.bench.paired import paired_cost


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
