"""The batched engine's per-update diagnostics: every agent carries one dict per update (on-policy:
per rollout; off-policy: per training day with gradient steps) with its algorithm's quantities of
:mod:`nutribench.diagnostics`, finite, its own (not the batch's), and a resumed batch returns them
all."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch as th

from nutribench import diagnostics as names
from nutribench.agents.api import NORM_EPS
from nutribench.agents.config import load_agent_config
from nutribench.engine.checkpoint import Checkpoint
from nutribench.engine.train import train_batched

ON_POLICY = {names.POLICY_LOSS, names.VALUE_LOSS, names.ENTROPY_LOSS, names.EXPLAINED_VARIANCE, names.GRAD_NORM}
KEYS = {
    "mc": ON_POLICY | {names.LEARNING_RATE, names.RETURN_SCALE},
    "ppo": ON_POLICY | {names.APPROX_KL, names.CLIP_FRACTION, names.LEARNING_RATE, names.RETURN_SCALE},
    "gru_ppo": ON_POLICY | {names.APPROX_KL, names.CLIP_FRACTION, names.LEARNING_RATE, names.RETURN_SCALE},
    "ddqn": {names.VALUE_LOSS, names.GRAD_NORM, names.Q_MEAN, names.LEARNING_RATE, names.EPSILON},
    "sac": {names.VALUE_LOSS, names.ACTOR_LOSS, names.Q_MEAN, names.ENT_COEF, names.LEARNING_RATE},
}
#: (the config's short form, days, env steps at each update's end)
SETUPS = {
    "mc": ({}, 3, [50, 100, 150]),
    "ppo": (dict(n_steps=100, batch_size=50, n_epochs=2), 4, [100, 200]),
    "gru_ppo": (dict(n_steps=100, batch_size=50, n_epochs=2), 4, [100, 200]),
    # updates from step 61 on: days 2 and 3 (none on the budget's last step)
    "ddqn": (dict(learning_starts=60, target_update_interval=40, buffer_size=300), 3, [100, 150]),
    # updates from step 129 on: day 3
    "sac": (dict(buffer_size=200), 3, [150]),
}
JOBS = [("run0", 0), ("run6", 1)]


def config(algo: str):
    return load_agent_config(algo).model_copy(update=SETUPS[algo][0])


@pytest.mark.parametrize("algo", list(SETUPS))
def test_each_agent_carries_one_dict_per_update_with_its_algorithm_s_finite_quantities(algo: str) -> None:
    _, days, timesteps = SETUPS[algo]
    cfg = config(algo)
    agents = train_batched(JOBS, cfg, days)
    for agent in agents:
        rows = agent.diagnostics
        assert [r[names.UPDATE] for r in rows] == list(range(len(timesteps)))
        assert [r[names.TIMESTEP] for r in rows] == timesteps
        for r in rows:
            assert set(r) == {names.UPDATE, names.TIMESTEP} | KEYS[algo]
            assert set(r) <= set(names.COLUMNS)
            assert all(isinstance(v, (int, float)) and math.isfinite(v) for v in r.values()), r
    a, b = (agent.diagnostics for agent in agents)
    quantity = names.VALUE_LOSS
    assert all(x[quantity] != y[quantity] for x, y in zip(a, b))  # each agent's own, not the batch's
    first = a[0]
    if algo in ("mc", "ppo", "gru_ppo"):
        assert first[names.LEARNING_RATE] == cfg.learning_rate
        assert 0.0 <= first[names.ENTROPY_LOSS] + math.log(2) <= math.log(2)  # minus a mean entropy of 2 actions
        last = agents[0].diagnostics[-1]  # the budget ends at the last update: the statistics then are the agent's
        assert last[names.RETURN_SCALE] == pytest.approx(np.sqrt(agents[0].vec_normalize.ret_rms.var + NORM_EPS))
    if algo in ("ppo", "gru_ppo"):
        assert all(0.0 <= r[names.CLIP_FRACTION] <= 1.0 and r[names.APPROX_KL] >= 0.0 for r in a + b)
    if algo == "ddqn":
        lr = sorted([cfg.learning_rate_end, cfg.learning_rate_start])
        eps = sorted([cfg.exploration_final_eps, cfg.exploration_initial_eps])
        for r in a:  # means of a schedule's values: within its range, up to the rounding of a mean
            assert lr[0] * (1 - 1e-9) <= r[names.LEARNING_RATE] <= lr[1] * (1 + 1e-9)
            assert eps[0] * (1 - 1e-9) <= r[names.EPSILON] <= eps[1] * (1 + 1e-9)
    if algo == "sac":
        assert first[names.ENT_COEF] == pytest.approx(cfg.alpha)
        assert first[names.LEARNING_RATE] == pytest.approx(cfg.critic_learning_rate)


@pytest.mark.parametrize("algo", ["ppo", "sac"])
def test_an_agent_s_diagnostics_do_not_depend_on_the_batch_it_trains_in(algo: str) -> None:
    """Agent (run0, seed 0) alone and beside another: the same diagnostics, up to the float
    rounding of a different K (the means are per agent, not over the batch)."""
    _, days, _ = SETUPS[algo]
    alone = train_batched(JOBS[:1], config(algo), days)[0].diagnostics
    beside = train_batched(JOBS, config(algo), days)[0].diagnostics
    assert len(alone) == len(beside)
    for x, y in zip(alone, beside):
        assert x.keys() == y.keys()
        for key in x:
            assert x[key] == pytest.approx(y[key], rel=1e-4, abs=1e-6), key


class Stopped(Exception):
    """Stands for the process being killed."""


@pytest.mark.parametrize("algo,days,stop_day", [("mc", 4, 2), ("ddqn", 4, 2)])
def test_a_resumed_batch_returns_the_diagnostics_of_the_whole_run(algo: str, days: int, stop_day: int, tmp_path):
    cfg = config(algo)
    whole = train_batched(JOBS, cfg, days)

    def kill(j: int, row: dict) -> None:
        if row["episode"] == stop_day:
            raise Stopped

    path = tmp_path / "batch.pt"
    with pytest.raises(Stopped):
        train_batched(JOBS, cfg, days, on_episode=kill, checkpoint=Checkpoint(path, every_seconds=0))
    checkpoint = Checkpoint(path, every_seconds=0)
    before_stop = len(checkpoint.state["diagnostics"][0])
    assert before_stop > 0  # the checkpoint holds the updates before the stop
    resumed = train_batched(JOBS, cfg, days, checkpoint=checkpoint)
    for x, y in zip(whole, resumed, strict=True):
        assert len(x.diagnostics) > before_stop
        assert x.diagnostics == y.diagnostics


@pytest.mark.skipif(not th.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("algo", list(SETUPS))
def test_on_cuda_each_agent_carries_its_finite_diagnostics(algo: str) -> None:
    _, days, timesteps = SETUPS[algo]
    for agent in train_batched(JOBS, config(algo), days, device="cuda"):
        assert [r[names.TIMESTEP] for r in agent.diagnostics] == timesteps
        for r in agent.diagnostics:
            assert set(r) == {names.UPDATE, names.TIMESTEP} | KEYS[algo]
            assert all(math.isfinite(v) for v in r.values()), r
