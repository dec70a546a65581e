"""Batch invariance: on the CPU, a job's numbers do not depend on its batch mates (K, their
regimes and seeds, its place in the batch), bit for bit; and the same batch gives the same
numbers twice. docs/batched-engine.md ("Reproducibility") says what is and is not claimed.

The three operations whose rounding depended on K, each pinned by a test that failed before
its fix: torch's fused CPU Adam (vector body and scalar tail round ``exp_avg_sq``
differently), the per-agent gradient norm over stacked rows (a reduction over dims (0, 2)
blocked by K), and a batch of one matrix-vector product (GRU-PPO's critic) at K = 1.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch as th

from nutribench.agents.config import load_agent_config
from nutribench.engine.gru_ppo import StackedGRUActorCritic
from nutribench.engine.stacked import clip_grad_norm_per_agent, make_adam
from nutribench.engine.train import train_batched

#: short runs that update several times (the settings of tests/engine_fingerprint.py)
SHORT = {
    "ppo": ({}, 10),  # the shipped config: one 500-step rollout, 80 gradient steps
    "mc": ({}, 12),
    "gru_ppo": (dict(n_steps=100, batch_size=50, n_epochs=2), 12),
    "ddqn": (dict(learning_starts=60, target_update_interval=40, buffer_size=300), 15),
    "sac": (dict(buffer_size=200), 15),
}
MATES = [("run0", 1), ("run3", 2), ("run6", 5), ("run2", 3), ("run0", 7), ("run5", 4), ("run1", 9)]


def _generator(seed: int) -> th.Generator:
    return th.Generator().manual_seed(seed)


def _agent0_adam(k: int, n: int, steps: int = 60) -> tuple[th.Tensor, th.Tensor]:
    """Agent 0's parameter and ``exp_avg_sq`` after ``steps`` Adam steps on a ``(k, 1, n)``
    stacked parameter, agent 0's gradients the same at every ``k``."""
    p = th.cat([th.randn(1, 1, n, generator=_generator(0)), th.randn(k - 1, 1, n, generator=_generator(1))])
    p.requires_grad_()
    opt = make_adam([p], 1e-3, 1e-5)
    for s in range(steps):
        grad = th.randn(k, 1, n, generator=_generator(1000 + s)) * 1e-3
        grad[0] = th.randn(1, n, generator=_generator(s)) * 1e-3
        p.grad = grad
        opt.step()
    return p[0].detach().clone(), opt.state[p]["exp_avg_sq"][0].clone()


@pytest.mark.parametrize("n", [1, 2, 3, 128])
def test_adam_steps_each_agent_alike_at_every_k(n: int) -> None:
    """The output biases (1 to 3 floats per agent) included: torch's fused kernel alone
    rounds them differently once K x n fills a vector (K = 3 for PPO's 3)."""
    p1, v1 = _agent0_adam(1, n)
    for k in (2, 3, 8, 35):
        pk, vk = _agent0_adam(k, n)
        assert th.equal(p1, pk) and th.equal(v1, vk), (n, k)


def test_gradient_norm_of_stacked_rows_is_each_agents_at_every_k() -> None:
    """GRU-PPO's cells are ``2K`` rows (row ``i * K + j`` is agent ``j``'s ``i``-th); a sum
    over dims (0, 2) at once rounded agent 0's norm differently at K = 1 and K > 1 for about
    half of such gradients (its biases' ``(2K, 1, 384)``), so twenty are tried."""

    def norm0(k: int, rows: th.Tensor) -> th.Tensor:
        grad = th.randn(2 * k, 1, 384, generator=_generator(7))
        grad[0], grad[k] = rows[0], rows[1]
        p = th.zeros(2 * k, 1, 384, requires_grad=True)
        p.grad = grad
        return clip_grad_norm_per_agent([p], float("inf"), k)[0]

    for seed in range(20):
        rows = th.randn(2, 1, 384, generator=_generator(seed))
        for k in (2, 3, 8):
            assert th.equal(norm0(1, rows), norm0(k, rows)), (seed, k)


def test_gru_critic_values_alike_alone_and_in_a_batch() -> None:
    def values0(k: int) -> th.Tensor:
        net = StackedGRUActorCritic(k, 13, generators=[_generator(50 + j) for j in range(k)])
        obs = th.randn(k, 1, 30, 13, generator=_generator(9))
        obs[0] = th.randn(1, 30, 13, generator=_generator(1))
        return net.sequences(obs)[1][0].detach()

    assert th.equal(values0(1), values0(3))


def _runs(algo: str, jobs: list) -> list[tuple[list, list[np.ndarray]]]:
    """Each job's training days and weights after a short run of ``jobs`` as one batch."""
    update, days = SHORT[algo]
    agents = train_batched(jobs, load_agent_config(algo).model_copy(update=update), days)
    return [(a.train_episodes, [p.detach().numpy().copy() for p in a.model.policy.parameters()]) for a in agents]


def _same(a: tuple[list, list[np.ndarray]], b: tuple[list, list[np.ndarray]]) -> bool:
    return a[0] == b[0] and len(a[1]) == len(b[1]) and all(np.array_equal(x, y) for x, y in zip(a[1], b[1]))


@pytest.mark.slow
@pytest.mark.parametrize("algo", list(SHORT))
def test_a_job_trains_alike_alone_first_and_last_in_a_batch_of_8(algo: str) -> None:
    """Its training days and every weight bit for bit (before the fixes, all but DDQN's
    differed within these days)."""
    job = ("run6", 0)
    alone = _runs(algo, [job])[0]
    assert _same(alone, _runs(algo, [job, *MATES])[0])
    assert _same(alone, _runs(algo, [*MATES, job])[-1])


def test_ppo_trains_alike_alone_and_in_a_batch_of_8() -> None:
    """The quick form of the test above (PPO's first update, 10 days)."""
    job = ("run6", 0)
    assert _same(_runs("ppo", [job])[0], _runs("ppo", [job, *MATES])[0])


def test_the_same_batch_trains_the_same_twice() -> None:
    jobs = [("run0", 0), ("run6", 3), ("run3", 1)]
    first, again = _runs("mc", jobs), _runs("mc", jobs)
    assert all(_same(a, b) for a, b in zip(first, again))
