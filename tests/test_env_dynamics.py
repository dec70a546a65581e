"""Exact dynamics: a hand-computed example, kernel and state properties, the reward formula."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from nutribench.env import NutriRLEnv
from nutribench.env.nutri_env import absorption_schedule, kernel


def _w(tau: float, sigma: float) -> list[float]:
    """Kernel weights of offsets 1..ceil(6 sigma), written out independently of the package."""
    raw = [math.exp(-0.5 * ((k - tau) / sigma) ** 2) for k in range(1, math.ceil(6 * sigma) + 1)]
    total = sum(raw)
    return [x / total for x in raw]


def test_hand_computed_example(tiny_regime):
    # food a = (0.5, 0, 0.1): C after exactly 1 step (tau 1, sigma 0), P in the same step.
    # food b = (0, 0.2, 0.4): F over steps t+1..t+6 (tau 2, sigma 1), P at t+3 (round(2.6)).
    w = _w(2.0, 1.0)
    assert len(w) == 6
    foods = [0, 1, 0, 1, 0, 1, 1, 0]
    actions = [1, 1, 0, 1, 0, 0, 0, 1]
    # expected absorbed increments per step (C, F, P), derived by hand from the schedule above
    inc = {
        1: (0.0, 0.0, 0.1),  # a eaten at 1: P now
        2: (0.5, 0.0, 0.0),  # a's C from step 1
        3: (0.0, 0.2 * w[0], 0.0),  # b eaten at 2: F k=1
        4: (0.0, 0.2 * w[1], 0.0),  # b@2 k=2
        5: (0.0, 0.2 * w[2] + 0.2 * w[0], 0.4),  # b@2 k=3, b@4 k=1, P of b@2
        6: (0.0, 0.2 * w[3] + 0.2 * w[1], 0.0),
        7: (0.0, 0.2 * w[4] + 0.2 * w[2], 0.4),  # P of b@4
        8: (0.0, 0.2 * w[5] + 0.2 * w[3], 0.1),  # a eaten at 8: P now; its C (step 9) never arrives
    }
    env = NutriRLEnv(tiny_regime)
    obs, _ = env.reset(options={"foods": foods})
    assert env.horizon == 8
    s = np.zeros(3)
    d_prev = 3.0
    for t in range(1, 9):
        obs, r, term, trunc, info = env.step(actions[t - 1])
        s = s + np.array(inc[t])
        np.testing.assert_allclose(info["state"], s, rtol=0, atol=1e-12, err_msg=f"step {t}")
        np.testing.assert_allclose(obs[:3], s, rtol=1e-6)
        d = np.abs(s - 1).sum()
        over = np.maximum(s - 1, 0)
        expected = 1.0 * (d_prev - d) - 0.5 * math.tanh(d / 0.5) - 2.0 * math.tanh((over**2).sum())
        assert r == pytest.approx(expected, abs=1e-12)
        d_prev = d
        assert not term
        assert trunc == (t == 8)
    assert info["foods_consumed"] == 4
    assert obs[3:].sum() == 0  # nothing offered after the day ends


@settings(max_examples=200, deadline=None)
@given(tau=st.floats(0, 25), sigma=st.floats(0, 15))
def test_kernel_sums_to_one_and_delivers_the_whole_amount(tau, sigma):
    offsets, w = kernel(tau, sigma)
    assert w.sum() == pytest.approx(1.0, abs=1e-12)
    assert np.all(w >= 0)
    if sigma == 0:
        assert offsets.tolist() == [math.floor(tau + 0.5)]
    else:
        assert offsets[0] == 1 and offsets[-1] == math.ceil(6 * sigma)
    masses = np.array([[0.3, 0.7, 1.1]])
    A = absorption_schedule(masses, np.full((1, 3), tau), np.full((1, 3), sigma), length=int(offsets[-1]) + 1)
    np.testing.assert_allclose(A.sum(axis=1), masses, atol=1e-12)


def test_kernel_weights_follow_the_gaussian_formula():
    offsets, w = kernel(4.3, 1.2)
    np.testing.assert_allclose(w, _w(4.3, 1.2), atol=1e-15)
    assert offsets.tolist() == list(range(1, 9))


@settings(max_examples=25, deadline=None)
@given(
    regime=st.sampled_from([f"run{k}" for k in range(7)]),
    seed=st.integers(0, 2**31 - 1),
    p_eat=st.floats(0, 1),
)
def test_state_monotone_and_absorbed_never_exceeds_eaten(regime, seed, p_eat):
    env = NutriRLEnv(regime)
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    eaten = np.zeros(3)
    prev = np.zeros(3)
    done = False
    while not done:
        food = env.offered
        a = int(rng.random() < p_eat)
        if a:
            eaten += env.masses[food]
        obs, r, term, trunc, info = env.step(a)
        s = info["state"]
        assert np.all(s >= prev - 1e-15)
        assert np.all(s <= eaten + 1e-9)
        parts = info["reward_progress"] + info["reward_comfort"] + info["reward_overshoot"]
        assert r == pytest.approx(parts, abs=1e-12)
        assert info["reward_comfort"] <= 0 and info["reward_overshoot"] <= 0
        assert info["overshoot"].tolist() == (s > 1.0).tolist()
        prev = s
        done = term or trunc


def test_run0_absorbs_in_the_same_step():
    env = NutriRLEnv("run0")
    env.reset(seed=3)
    food = env.offered
    obs, *_, info = env.step(1)
    np.testing.assert_allclose(info["state"], env.masses[food], atol=1e-15)
    np.testing.assert_allclose(obs[:3], env.masses[food], rtol=1e-6)


def test_delayed_regime_absorbs_nothing_in_the_eating_step():
    env = NutriRLEnv("run3")
    env.reset(seed=3)
    *_, info = env.step(1)
    assert np.all(info["state"] == 0)
    assert env.pending_by_horizon().sum() > 0


def test_absorption_after_the_horizon_never_arrives():
    env = NutriRLEnv("run6")  # long delays: a food eaten late mostly arrives after step H
    foods = [0] * env.horizon
    env.reset(options={"foods": foods})
    actions = [0] * (env.horizon - 3) + [1, 1, 1]
    for a in actions:
        *_, info = env.step(a)
    eaten = 3 * env.masses[0]
    assert np.all(info["state"] < eaten)
    expected = sum(env.schedule[0, :k].sum(axis=0) for k in (1, 2, 3))  # offsets that fit before H
    np.testing.assert_allclose(info["state"], expected, atol=1e-12)


def test_observation_layout_and_one_hot():
    env = NutriRLEnv("run2")
    obs, _ = env.reset(seed=0)
    assert obs.shape == (13,) and obs.dtype == np.float32
    assert obs[3:].sum() == 1 and obs[3 + env.offered] == 1
    assert np.all(obs[:3] == 0)


def test_step_after_end_and_bad_action_are_errors():
    env = NutriRLEnv("run0")
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(2)
    for _ in range(env.horizon):
        env.step(0)
    with pytest.raises(RuntimeError, match="reset"):
        env.step(0)


def test_foods_option_is_validated():
    env = NutriRLEnv("run0")
    with pytest.raises(ValueError, match="shape"):
        env.reset(options={"foods": [0, 1, 2]})
    with pytest.raises(ValueError, match="index the catalog"):
        env.reset(options={"foods": [10] * env.horizon})
