"""Throughput benchmarks (``nutribench bench ...``): medians of repeated timed runs."""

from __future__ import annotations

import statistics
import time

import numpy as np

from nutribench.env import NutriRLEnv, NutriRLVectorEnv


def _median_rate(fn, steps: int, repeats: int) -> float:
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        rates.append(steps / (time.perf_counter() - t0))
    return statistics.median(rates)


def single_env_rate(regime: str, steps: int = 100_000, repeats: int = 5, seed: int = 0) -> float:
    """Env-steps per second of one NutriRLEnv under uniformly random actions."""
    env = NutriRLEnv(regime)
    actions = np.random.default_rng(seed).integers(0, 2, size=steps).tolist()
    H = env.horizon

    def run():
        env.reset(seed=seed)
        step, reset = env.step, env.reset
        k = 0
        for a in actions:
            step(a)
            k += 1
            if k == H:
                reset()
                k = 0

    return _median_rate(run, steps, repeats)


def vector_env_rate(regime: str, num_envs: int, vector_steps: int = 1000, repeats: int = 5, seed: int = 0) -> float:
    """Env-steps per second of a NutriRLVectorEnv under uniformly random actions."""
    env = NutriRLVectorEnv(num_envs, regime=regime)
    rng = np.random.default_rng(seed)
    actions = rng.integers(0, 2, size=(64, num_envs))

    def run():
        env.reset(seed=seed)
        step = env.step
        for k in range(vector_steps):
            step(actions[k % 64])

    return _median_rate(run, vector_steps * num_envs, repeats)


def bench_env(regimes=("run0", "run6"), sizes=(1, 64, 1024, 4096), repeats: int = 5) -> list[dict]:
    rows = []
    for regime in regimes:
        rows.append({"regime": regime, "env": "single", "num_envs": 1, "steps_per_s": single_env_rate(regime, repeats=repeats)})
        for n in sizes:
            vsteps = max(200, min(20_000, 2_000_000 // n))
            rows.append(
                {"regime": regime, "env": "vector", "num_envs": n, "steps_per_s": vector_env_rate(regime, n, vsteps, repeats)}
            )
    return rows
