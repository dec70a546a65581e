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
from nutribench.engine.on_policy import gae
from nutribench.engine.stacked import StackedAdam, clip_grad_norm_per_agent
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
    opt = StackedAdam([p], 1e-3, 1e-5)
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


def test_an_agents_own_rate_steps_it_as_that_rate_alone_does() -> None:
    """A rate per agent (stacked tuning trials, frozen agents at rate 0) steps each agent bit
    for bit as one float rate steps it in a batch of its own. Before StackedAdam the batch ran
    Adam at rate 1 and scaled each agent's step afterwards, which rounds unlike a step at the
    rate (on an AMD EPYC the stacked GRU-PPO trials left their one-agent runs by 0.7 %)."""
    rates = np.array([3e-4, 1e-3, 0.0, 7.7e-5])
    k, n = len(rates), 3  # 3 floats per agent: a vector tail for some K
    grads = [th.randn(k, 1, n, generator=_generator(s)) for s in range(30)]
    stacked = th.randn(k, 1, n, generator=_generator(99)).requires_grad_()
    start = stacked.detach().clone()
    opt = StackedAdam([stacked], rates, 1e-5)
    for g in grads:
        stacked.grad = g.clone()
        opt.step()
    for j, rate in enumerate(rates):
        alone = start[j : j + 1].clone().requires_grad_()
        opt1 = StackedAdam([alone], float(rate), 1e-5)
        for g in grads:
            alone.grad = g[j : j + 1].clone()
            opt1.step()
        assert th.equal(alone.detach()[0], stacked.detach()[j]), j
    assert th.equal(stacked.detach()[2], start[2])  # rate 0: not moved


def test_stacked_adam_is_torchs_adam_up_to_rounding() -> None:
    """A step at rate 1 scaled by the rate is torch's step at that rate (SB3's optimiser) up to
    rounding: each step rounds the weight once more, at most an ulp of a weight under 4 (2.4e-7),
    so 60 steps stay within 60 x 2.4e-7 = 1.4e-5 of torch's, while they move it by about 1e-3
    each (the bound is a few % of the move, not a blanket)."""
    p0 = th.randn(8, 1, 19, generator=_generator(3)).clamp(-3.9, 3.9)
    ours, theirs = p0.clone().requires_grad_(), p0.clone().requires_grad_()
    opt, ref = StackedAdam([ours], 1e-3, 1e-5), th.optim.Adam([theirs], lr=1e-3, eps=1e-5, foreach=False)
    for s in range(60):
        g = th.randn(8, 1, 19, generator=_generator(200 + s))
        ours.grad, theirs.grad = g.clone(), g.clone()
        opt.step()
        ref.step()
    np.testing.assert_allclose(ours.detach().numpy(), theirs.detach().numpy(), rtol=0, atol=60 * 2.4e-7)
    assert (theirs - p0).abs().mean() > 1e-3  # the steps were real (60 steps of about 1e-3)


def test_settings_per_agent_round_as_one_float_does() -> None:
    """GAE's gamma * lambda and the gradient clip's max_norm: an agent's numbers are the same
    whether its setting is one float or its entry of a (K,) array."""
    rng = np.random.default_rng(0)
    k, t = 3, 200
    rewards, values = rng.normal(size=(k, t)).astype(np.float32), rng.normal(size=(k, t)).astype(np.float32)
    starts = (np.arange(t) % 50 == 0)[None].repeat(k, 0).astype(np.float32)
    last, dones = rng.normal(size=k).astype(np.float32), np.zeros(k, dtype=bool)
    gammas, lams = np.array([0.99, 0.95, 0.9731]), np.array([0.95, 0.9, 0.9912])
    adv, ret = gae(rewards, values, starts, last, dones, gammas, lams)
    for j in range(k):
        s = slice(j, j + 1)
        adv1, ret1 = gae(rewards[s], values[s], starts[s], last[s], dones[s], float(gammas[j]), float(lams[j]))
        assert np.array_equal(adv1[0], adv[j]) and np.array_equal(ret1[0], ret[j]), j

    max_norms = np.array([0.5, 1.5, 0.3])
    grads = th.randn(k, 1, 40, generator=_generator(5)) * 3
    p = th.zeros(k, 1, 40, requires_grad=True)
    p.grad = grads.clone()
    clip_grad_norm_per_agent([p], max_norms)
    for j in range(k):
        q = th.zeros(1, 1, 40, requires_grad=True)
        q.grad = grads[j : j + 1].clone()
        clip_grad_norm_per_agent([q], float(max_norms[j]))
        assert th.equal(q.grad[0], p.grad[j]), j
