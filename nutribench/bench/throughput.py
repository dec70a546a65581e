"""Throughput benchmarks (``nutribench bench env|train``): medians of repeated timed runs."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from nutribench.env import NutriRLEnv, NutriRLVectorEnv


def timings(call: Callable[[], Any], repeats: int) -> list[float]:
    """The wall seconds of each of ``repeats`` calls."""
    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        call()
        seconds.append(time.perf_counter() - t0)
    return seconds


def _median_rate(fn: Callable[[], Any], steps: int, repeats: int) -> float:
    return statistics.median(steps / t for t in timings(fn, repeats))


def single_env_rate(regime: str, steps: int = 100_000, repeats: int = 5, seed: int = 0) -> float:
    """Env-steps per second of one NutriRLEnv under uniformly random actions."""
    env = NutriRLEnv(regime)
    actions = np.random.default_rng(seed).integers(0, 2, size=steps).tolist()
    H = env.horizon

    def run():
        env.reset(seed=seed)
        step, reset = env.step, env.reset
        for k, a in enumerate(actions, 1):
            step(a)
            if k % H == 0:
                reset()

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
        runs = [("single", 1, single_env_rate(regime, repeats=repeats))]
        runs += [
            ("vector", n, vector_env_rate(regime, n, max(200, min(20_000, 2_000_000 // n)), repeats)) for n in sizes
        ]
        rows += [{"regime": regime, "env": env, "num_envs": n, "steps_per_s": rate} for env, n, rate in runs]
    return rows


# --------------------------------------------------------------------------- training
#: Paper grid: 7 regimes x 5 algorithms x 5 seeds x 5000 episodes of 50 steps.
PAPER_GRID = {"regimes": 7, "seeds": 5, "episodes": 5000}
#: the paper grid's env-steps per algorithm
PAPER_GRID_STEPS = PAPER_GRID["regimes"] * PAPER_GRID["seeds"] * PAPER_GRID["episodes"] * 50


def bench_config(algo: str):
    """The shipped config, with DDQN's and SAC's learning start moved to step 0 so that the
    timed steps are learning steps (as are 96 % of a 5000-episode DDQN job's, and all but 128
    of a SAC job's)."""
    from nutribench.agents.config import load_agent_config

    cfg = load_agent_config(algo)
    if "learning_starts" in type(cfg).model_fields:  # a replay's warm-up
        cfg = cfg.model_copy(update={"learning_starts": 0})
    return cfg


def _bare_sb3_seconds(algo: str, regime: str, episodes: int, seed: int, bare_cls: str) -> float:
    """``model.learn`` of the SB3 class ``bare_cls`` (an entry point: SB3's ``PPO``, ``DQN``
    or our ``DoubleDQN``, the registry entry's ``bare``) with the same hyperparameters on the
    same env, without nutribench's episode recording."""
    from nutribench.agents import algos
    from nutribench.agents.api import make_train_env, single_threaded
    from nutribench.agents.registry import import_entry_point
    from nutribench.config import load_env_config

    with single_threaded():  # the caller's thread count back afterwards
        t0 = time.perf_counter()  # like the timed train(): config, env and model set-up included
        env_cfg = load_env_config(regime)
        cfg = bench_config(algo)
        _, env = make_train_env(env_cfg, cfg)
        # same hyperparameters and networks; the class decides the update (DQN: the vanilla max target)
        cls = import_entry_point(bare_cls)
        model = algos.build_model(cfg, env, seed=seed, horizon=env_cfg.reward.horizon, cls=cls)
        model.learn(total_timesteps=episodes * env_cfg.reward.horizon)
        return time.perf_counter() - t0


def bench_train(
    algos: list[str], regime: str = "run0", episodes: int = 100, repeats: int = 3, seed: int = 0
) -> list[dict]:
    """Env-steps per second of ``nutribench.agents.train`` for each algorithm, and of bare
    SB3 PPO and DQN on the same env (medians over ``repeats``); plus the CPU-hours the paper
    grid would take at that rate, one job per core. A nutribench row with a bare reference
    has ``vs_bare``: the median over repeats of (bare seconds / nutribench seconds) of the
    same repeat, i.e. nutribench's throughput as a fraction of bare SB3's. (What the training
    diagnostics cost is a finished study's bench: ``reports/diagnostics_cost/``.)"""
    import nutribench.agents.registry as registry
    from nutribench.agents.api import train

    steps = episodes * 50
    rows = []
    for algo in algos:
        cfg = bench_config(algo)
        bare_refs = list(registry.get(cfg.algo).bare)
        # repeats interleaved (ours, bare, ours, bare, ...) so that a machine that speeds up
        # or slows down during the benchmark shifts both sides alike
        times: list[float] = []
        bare_times: dict[str, list[float]] = {cls_name: [] for cls_name, _ in bare_refs}
        for _ in range(repeats):
            times += timings(lambda c=cfg: train(regime, c, seed=seed, episodes=episodes), 1)
            for cls_name, _ in bare_refs:
                bare_times[cls_name].append(_bare_sb3_seconds(algo, regime, episodes, seed, cls_name))
        rate = steps / statistics.median(times)
        row = {"what": f"nutribench {algo}", "algo": algo, "steps_per_s": rate, "bare": False}
        if bare_refs:  # the first bare row is the one the plumbing's overhead is measured against
            ref = bare_times[bare_refs[0][0]]
            row["vs_bare"] = statistics.median(b / t for b, t in zip(ref, times))  # paired, per repeat
        rows.append(row)
        for cls_name, label in bare_refs:
            rate = steps / statistics.median(bare_times[cls_name])
            rows.append({"what": label, "algo": algo, "steps_per_s": rate, "bare": True})
    for r in rows:
        r["paper_grid_cpu_hours"] = PAPER_GRID_STEPS / r["steps_per_s"] / 3600
    return rows


def matmul_flops_per_s(
    k: int = 35, batch: int = 64, n_in: int = 256, n_out: int = 128, repeats: int = 200, device: str = "cpu"
) -> float:
    """This machine's dense float32 batched-matmul rate on one thread (or on the CUDA
    ``device``), at the shape of the batched engine's largest layer (K agents x a
    minibatch): median of 5 timings."""
    import torch

    from nutribench.agents.api import single_threaded
    from nutribench.engine.device import resolve_device

    dev = resolve_device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    rates = []
    with single_threaded():  # the caller's thread count back afterwards
        a, b = torch.randn(k, batch, n_in).to(dev), torch.randn(k, n_in, n_out).to(dev)
        out = torch.empty(k, batch, n_out, device=dev)
        torch.bmm(a, b, out=out)
        for _ in range(5):
            sync()
            t0 = time.perf_counter()
            for _ in range(repeats):
                torch.bmm(a, b, out=out)
            sync()
            rates.append(2 * k * batch * n_in * n_out * repeats / (time.perf_counter() - t0))
    return statistics.median(rates)


def bench_train_batched(
    algo: str = "ppo", k_regimes: int = 7, k_seeds: int = 5, episodes: int = 20, repeats: int = 3, device: str = "cpu"
) -> dict:
    """Env-steps per second of the batched engine training K = regimes x seeds agents of
    ``algo`` at once in one process (one thread; DDQN and SAC learning from the first step), the arithmetic it does per env step, this
    machine's matmul rate (on ``device``, where the engine trains), the share of that floor
    reached, and the paper grid's wall time for this algorithm at that rate: on the CPU with
    batches side by side on all the cores, on a GPU as one batch of K = 35 there."""
    from nutribench import SHIPPED_REGIMES
    from nutribench.engine.device import resolve_device
    from nutribench.engine.train import train_batched
    from nutribench.scheduler.executors import core_count

    cfg = bench_config(algo)  # DDQN and SAC learning from the first step, as in the SB3 engine's rows
    jobs = [(r, s) for r in SHIPPED_REGIMES[:k_regimes] for s in range(k_seeds)]
    times = timings(lambda: train_batched(jobs, cfg, episodes, device=device), repeats)
    steps = len(jobs) * episodes * 50
    rate = steps / statistics.median(times)
    from nutribench.agents.registry import batched_class
    from nutribench.engine.off_policy import BatchedOffPolicyAlgorithm

    flops = batched_class(cfg.algo).flops_per_env_step(cfg)  # its matrix products
    off_policy = issubclass(batched_class(cfg.algo), BatchedOffPolicyAlgorithm)  # its minibatch is the replay's
    peak = matmul_flops_per_s(k=len(jobs), batch=cfg.batch_size if off_policy else 64, device=device)
    # on the CPU, batches side by side on all the cores; on a GPU, the one batch on it
    on_gpu = resolve_device(device).type == "cuda"
    cores = 1 if on_gpu else min(core_count(), PAPER_GRID["regimes"] * PAPER_GRID["seeds"])
    return {
        "algo": algo,
        "k": len(jobs),
        "episodes": episodes,
        "steps_per_s": rate,
        "flops_per_step": flops,
        "matmul_flops_per_s": peak,
        "floor_share": rate * flops / peak,
        "paper_grid_wall_hours": PAPER_GRID_STEPS / rate / cores / 3600,
        "paper_grid_floor_hours": PAPER_GRID_STEPS * flops / peak / cores / 3600,
        "cores": cores,
    }
