"""``nutribench bench tune``: tuning trials per hour, stacked in batched processes against one
SB3 process per trial (rl-zoo3's way), for the same trials on the same machine in one run.

The trials are drawn once (a seeded random sample of the search space's continuous
parameters; the structural ones at the base agent's values, as a stack of ``nutribench tune
--stack`` shares them) and every arm trains exactly those: each trial one agent per (regime,
tuning seed) for ``days`` days, greedily evaluated on validation days every ``eval_every``
days, as ``nutribench tune`` trains it. Arms:

* ``sb3``: a pool of ``workers`` processes, one trial per task; a trial trains its agents one
  after another with the SB3 engine (:func:`nutribench.agents.api.train`);
* ``stacked``: ``workers`` processes, the trials split evenly between them, each process
  training its share as one batch (:func:`nutribench.engine.train.train_batched` with one
  config per agent).

Each arm's wall time includes its processes' start (what a user waits for); the rate is
trials per hour, and the ratio the stacked arm's rate over the SB3 arm's. Repeats alternate
the arms' order; medians are reported.
"""

from __future__ import annotations

import multiprocessing
import statistics
import time
from concurrent.futures import ProcessPoolExecutor
from typing import Any

from nutribench.engines import Engine

ARMS = (Engine.SB3.value, "stacked")


def draw_trials(space_name: str, trials: int, seed: int = 0) -> list[dict[str, Any]]:
    """``trials`` agent configs (as plain data): the continuous parameters of ``space_name``
    drawn at random (seeded), the structural ones at the base agent's values."""
    import optuna

    from nutribench.tuning.space import load_search_space
    from nutribench.tuning.stack import per_agent_fields
    from nutribench.tuning.study import quiet_optuna

    space = load_search_space(space_name)
    shared = per_agent_fields(space.base())
    if not shared:
        raise ValueError(f"search space {space_name!r}: its algorithm takes no per-agent settings: nothing to stack")
    continuous = {k: p for k, p in space.params.items() if k in shared}
    with quiet_optuna():
        study = optuna.create_study(sampler=optuna.samplers.RandomSampler(seed=seed))
    out = []
    for _ in range(trials):
        trial = study.ask()
        values = {k: p.suggest(trial, k) for k, p in continuous.items()}
        out.append(space.config(values).model_dump(mode="json"))
    return out


def _sb3_trial(cfg: dict[str, Any], jobs: list[tuple[str, int]], days: int, eval_every: int, val: int) -> None:
    from nutribench.agents.api import single_threaded, train
    from nutribench.agents.config import parse_agent_config

    config = parse_agent_config(cfg)
    with single_threaded():  # the caller's thread count back afterwards
        for regime, seed in jobs:
            train(regime, config, seed, days, eval_every=eval_every, val_episodes=val, diagnostics=False)


def _stacked_trials(
    cfgs: list[dict[str, Any]], jobs: list[tuple[str, int]], days: int, eval_every: int, val: int
) -> None:
    from nutribench.agents.config import parse_agent_config
    from nutribench.engine.train import train_batched

    configs = [parse_agent_config(c) for c in cfgs for _ in jobs]
    train_batched(jobs * len(cfgs), configs[0], days, eval_every=eval_every, val_episodes=val, agent_configs=configs)


def _time_arm(
    arm: str, cfgs: list[dict[str, Any]], jobs: list, days: int, eval_every: int, val: int, workers: int
) -> float:
    context = multiprocessing.get_context("spawn")
    start = time.perf_counter()
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        if arm == Engine.SB3:
            futures = [pool.submit(_sb3_trial, c, jobs, days, eval_every, val) for c in cfgs]
        else:
            shares = [cfgs[i::workers] for i in range(workers) if cfgs[i::workers]]
            futures = [pool.submit(_stacked_trials, share, jobs, days, eval_every, val) for share in shares]
        for f in futures:
            f.result()
    return time.perf_counter() - start


def bench_tune(
    space: str = "ppo",
    trials: int = 8,
    days: int = 20,
    regimes: tuple[str, ...] = ("run0", "run3"),
    seeds: tuple[int, ...] = (101, 102),
    eval_every: int = 10,
    val_episodes: int = 5,
    workers: int | None = None,
    repeats: int = 1,
    seed: int = 0,
) -> list[dict[str, Any]]:
    """One row per arm: wall seconds per repeat and their median, trials per hour, and (on the
    stacked row) the ratio of the rates."""
    import os

    workers = workers or os.cpu_count() or 1
    cfgs = draw_trials(space, trials, seed)
    jobs = [(r, s) for r in regimes for s in seeds]
    walls: dict[str, list[float]] = {a: [] for a in ARMS}
    for rep in range(repeats):
        for arm in ARMS if rep % 2 == 0 else ARMS[::-1]:
            walls[arm].append(_time_arm(arm, cfgs, jobs, days, eval_every, val_episodes, workers))
    common = {"space": space, "trials": trials, "agents_per_trial": len(jobs), "days": days, "workers": workers}
    medians = {arm: statistics.median(walls[arm]) for arm in ARMS}
    rows = [
        {"arm": a, **common, "walls": walls[a], "wall_s": m, "trials_per_hour": trials / m * 3600}
        for a, m in medians.items()
    ]
    rows[1]["ratio"] = rows[1]["trials_per_hour"] / rows[0]["trials_per_hour"]
    return rows
