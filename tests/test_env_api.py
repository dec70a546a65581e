"""Gymnasium / SB3 conformance, registration, seeding, inspection API, rendering."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from stable_baselines3.common.env_checker import check_env as sb3_check_env

import nutribench
from nutribench.env import NutriRLEnv

REGIMES = [f"run{k}" for k in range(7)]


@pytest.mark.parametrize("regime", REGIMES)
def test_gymnasium_and_sb3_checkers(regime):
    check_env(gym.make(nutribench.ENV_ID, regime=regime).unwrapped, skip_render_check=False)
    sb3_check_env(NutriRLEnv(regime), warn=True)


def test_make_by_id_and_per_regime_ids():
    env = gym.make("nutribench/NutriRL-v0", regime="run3")
    assert env.unwrapped.config.name == "run3"
    env6 = gym.make("nutribench/NutriRL-run6-v0")
    assert env6.unwrapped.config.name == "run6"
    vec = gym.make_vec("nutribench/NutriRL-v0", num_envs=8, regime="run3")
    obs, _ = vec.reset(seed=0)
    assert obs.shape == (8, 13)
    assert type(vec).__name__ == "NutriRLVectorEnv"


def test_regime_by_path_and_model(tiny_regime):
    from nutribench.config import load_env_config

    assert NutriRLEnv(tiny_regime).horizon == 8
    cfg = load_env_config(tiny_regime)
    assert NutriRLEnv(cfg).config.sha256 == cfg.sha256


def _trajectory(env, seed, actions):
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, r, *_ = env.step(a)
        out += [obs, np.array([r])]
    return np.concatenate(out)


def test_same_seed_same_trajectory_different_seed_different():
    actions = np.random.default_rng(0).integers(0, 2, 50).tolist()
    a = _trajectory(NutriRLEnv("run4"), 7, actions)
    b = _trajectory(NutriRLEnv("run4"), 7, actions)
    c = _trajectory(NutriRLEnv("run4"), 8, actions)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_inspection_api():
    env = gym.make("nutribench/NutriRL-v0", regime="run5").unwrapped
    assert env.masses.shape == (10, 3) and env.tau.shape == (10, 3) and env.sigma.shape == (10, 3)
    np.testing.assert_array_equal(env.target, np.ones(3))
    assert env.horizon == 50 and env.reward_config.lo > 0
    r = env.config.regime.ranges
    assert np.all(env.tau[:, 0] >= r.tau.C.low) and np.all(env.tau[:, 0] <= r.tau.C.high)
    # masses are grams per portion over the target grams
    food = env.config.catalog.food[0]
    np.testing.assert_allclose(env.masses[0], food.grams() / env.config.catalog.target_grams.as_array())


def test_foods_option_plays_the_given_stream():
    env = NutriRLEnv("run1")
    stream = [(3 * k) % 10 for k in range(50)]
    env.reset(options={"foods": stream})
    seen = []
    for _ in range(50):
        seen.append(env.offered)
        env.step(0)
    assert seen == stream


def test_render_modes():
    env = NutriRLEnv("run2", render_mode="ansi")
    env.reset(seed=0)
    env.step(1)
    text = env.render()
    assert "step  1/50" in text and "offered" in text
    env = NutriRLEnv("run2", render_mode="rgb_array")
    env.reset(seed=0)
    img = env.render()
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.uint8 and img.std() > 0
    with pytest.raises(ValueError, match="render_mode"):
        NutriRLEnv("run0", render_mode="human")


def test_rgb_array_draws_the_nutrients_against_the_target_with_numpy_alone():
    """The picture: each nutrient's bar grows with what is absorbed (solid) and what is on its
    way (striped, the nutrient's colour too); the dashed target line sits at 1.0 of the scale."""
    from nutribench.env.nutri_env import COLORS, SIZE, nutrient_picture

    def colored(img, color):
        return int((img == np.array(color, dtype=np.uint8)).all(axis=2).sum())

    empty = nutrient_picture([0, 0, 0], [0, 0, 0], 0, 50)
    assert empty.shape == (*SIZE, 3) and all(colored(empty, c) == 0 for c in COLORS)
    half = nutrient_picture([0.5, 0.0, 0.0], [0, 0, 0], 10, 50)
    full = nutrient_picture([1.0, 0.0, 0.0], [0, 0, 0], 10, 50)
    assert 0 < colored(half, COLORS[0]) < colored(full, COLORS[0]) and colored(full, COLORS[1]) == 0
    on_way = nutrient_picture([0.5, 0.0, 0.0], [0.5, 0.0, 0.0], 10, 50)
    assert colored(half, COLORS[0]) < colored(on_way, COLORS[0]) < colored(full, COLORS[0])  # striped: half inked
    # the target line: black dashes on the row of 1.0, where a full bar's top edge is
    dark_rows = np.where(((empty == 0).all(axis=2)).sum(axis=1) > 100)[0]
    c_bar = np.where((full == np.array(COLORS[0], dtype=np.uint8)).all(axis=2).any(axis=1))[0]
    assert any(abs(int(r) - int(c_bar.min())) <= 1 for r in dark_rows)
    env = NutriRLEnv("run3", render_mode="rgb_array")
    env.reset(seed=0)
    for _ in range(5):
        env.step(1)
    assert np.array_equal(env.render(), env.render())
    assert colored(env.render(), COLORS[0]) > 0
