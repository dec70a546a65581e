"""``nutribench bench train --eval-every N``: what the evaluation during training costs. Each
repeat trains the same job (SB3 engine) or batch (batched engine: 7 regimes x 5 seeds at
once) twice, with and without ``eval_every``, in alternating order; the cost is the share of
the training time the evaluations take, paired per repeat
(:func:`~nutribench.bench.paired.paired_cost`, 95 % bootstrap interval over the repeats).
The two arms train identically (tests/test_validation.py), so the difference is the
evaluations alone."""

from __future__ import annotations

import statistics
import time

from nutribench.bench.paired import paired_cost


def _timed(algo: str, engine: str, regime: str, episodes: int, seed: int, **evaluation: int) -> float:
    """Seconds of one training of ``algo`` (``evaluation``: ``eval_every`` and ``val_episodes``, or none)."""
    from nutribench import SHIPPED_REGIMES
    from nutribench.agents.api import train
    from nutribench.engine.train import train_batched

    t0 = time.perf_counter()
    if engine == "batched":
        train_batched([(r, s) for r in SHIPPED_REGIMES for s in range(5)], algo, episodes, **evaluation)
    else:
        train(regime, algo, seed=seed, episodes=episodes, **evaluation)
    return time.perf_counter() - t0


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
    """Per algorithm: the median seconds with and without the evaluations, the evaluations
    made per run, and ``cost`` (with ``cost_ci``): their share of the training time."""
    rows = []
    evaluation = {"eval_every": eval_every, "val_episodes": val_episodes}
    for algo in algos:
        _timed(algo, engine, regime, 1, seed)  # untimed: one-off imports and set-up
        with_, without = [], []
        for i in range(repeats):
            for arm in (with_, without) if i % 2 == 0 else (without, with_):
                arm.append(_timed(algo, engine, regime, episodes, seed, **(evaluation if arm is with_ else {})))
        cost, lo, hi = paired_cost(with_, without)
        rows.append(
            {
                "algo": algo,
                "engine": engine,
                "with_s": statistics.median(with_),
                "without_s": statistics.median(without),
                "evaluations": episodes // eval_every,
                "cost": cost,
                "cost_ci": (lo, hi),
            }
        )
    return rows
